//! The control room attached to a measured run: what watching the bench from
//! another computer costs the loop.
//!
//! While a service set runs with its viewer (`--foxglove`) and bridge
//! (`--zenoh`), four clients connect, each on a thread of its own, retrying
//! until the services are up:
//! - a Foxglove client that subscribes to every channel and reads everything;
//! - one that subscribes to every channel and never reads again (its socket
//!   fills; the viewer's backlog for it must stay bounded);
//! - one that subscribes, reads, and tears its connection down mid-stream;
//! - a Zenoh subscriber of every channel, reading everything.
//!
//! The Foxglove clients speak the WebSocket protocol (`foxglove.sdk.v1`) with
//! a plain WebSocket library; they decode only the binary message header.

use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use jetbench_bridge::{Endpoint, RemoteBench};
use serde::Serialize;
use tungstenite::client::IntoClientRequest;
use tungstenite::Message;

/// How long a client keeps trying to reach a service that is still starting.
const CONNECT_FOR: Duration = Duration::from_secs(30);
/// How long the dropping client reads before it cuts its connection.
const DROP_AFTER: Duration = Duration::from_secs(3);

/// What the clients did.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ControlRoomReport {
    /// Messages the reading Foxglove client received.
    pub foxglove_read: u64,
    /// True when the stalled client connected and subscribed.
    pub foxglove_stalled: bool,
    /// Messages the dropping client read before it cut its connection.
    pub foxglove_dropped_after: u64,
    /// Samples the Zenoh subscriber received, and the `seq` gaps among them.
    pub zenoh_received: u64,
    pub zenoh_gaps: u64,
    /// What went wrong, per client (empty when all worked).
    pub errors: Vec<String>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Behaviour {
    Read,
    Stall,
    Drop,
}

/// The clients, running; [`ControlRoom::finish`] stops them.
pub struct ControlRoom {
    stop: Arc<AtomicBool>,
    read: Arc<AtomicU64>,
    threads: Vec<JoinHandle<Result<ClientResult, String>>>,
}

enum ClientResult {
    Foxglove(Behaviour, u64),
    Zenoh(u64, u64),
}

impl ControlRoom {
    /// Starts the clients of a service set that serves Foxglove at `foxglove`
    /// and Zenoh at `zenoh`, in bus namespace `namespace`. With `cpus`, each
    /// client (and every thread it starts) runs only there: the clients stand
    /// for another computer, so they are kept off the control chain's core.
    pub fn attach(foxglove: SocketAddr, zenoh: Endpoint, namespace: String, cpus: Vec<usize>) -> ControlRoom {
        let stop = Arc::new(AtomicBool::new(false));
        let read = Arc::new(AtomicU64::new(0));
        let mut threads = Vec::new();
        let pin = move || {
            let request = jetbench_stack::runtime::rt::RtRequest { cpus: cpus.clone(), ..Default::default() };
            move || {
                for refused in jetbench_stack::runtime::rt::apply(&request).refused {
                    tracing::warn!("control-room client: {refused}");
                }
            }
        };
        for behaviour in [Behaviour::Read, Behaviour::Stall, Behaviour::Drop] {
            let (stop, read, pin) = (Arc::clone(&stop), Arc::clone(&read), pin());
            threads.push(std::thread::spawn(move || {
                pin();
                foxglove_client(foxglove, behaviour, &stop, &read)
            }));
        }
        let (flag, pin) = (Arc::clone(&stop), pin());
        threads.push(std::thread::spawn(move || {
            pin();
            zenoh_client(&zenoh, &namespace, &flag)
        }));
        ControlRoom { stop, read, threads }
    }

    /// Stops the clients and says what they did.
    pub fn finish(self) -> ControlRoomReport {
        self.stop.store(true, Ordering::Relaxed);
        let mut report = ControlRoomReport::default();
        for thread in self.threads {
            match thread.join() {
                Ok(Ok(ClientResult::Foxglove(Behaviour::Read, n))) => report.foxglove_read = n,
                Ok(Ok(ClientResult::Foxglove(Behaviour::Stall, _))) => report.foxglove_stalled = true,
                Ok(Ok(ClientResult::Foxglove(Behaviour::Drop, n))) => report.foxglove_dropped_after = n,
                Ok(Ok(ClientResult::Zenoh(received, gaps))) => {
                    (report.zenoh_received, report.zenoh_gaps) = (received, gaps)
                }
                Ok(Err(e)) => report.errors.push(e),
                Err(_) => report.errors.push("a client thread panicked".into()),
            }
        }
        report.foxglove_read = report.foxglove_read.max(self.read.load(Ordering::Relaxed));
        report
    }
}

/// Retries `connect` until it works, `CONNECT_FOR` passes or a stop comes.
fn retry<T>(stop: &AtomicBool, what: &str, mut connect: impl FnMut() -> Result<T, String>) -> Result<T, String> {
    let deadline = Instant::now() + CONNECT_FOR;
    loop {
        match connect() {
            Ok(t) => return Ok(t),
            Err(e) if Instant::now() > deadline || stop.load(Ordering::Relaxed) => return Err(format!("{what}: {e}")),
            Err(_) => std::thread::sleep(Duration::from_millis(200)),
        }
    }
}

type Socket = tungstenite::WebSocket<TcpStream>;

fn foxglove_client(
    addr: SocketAddr,
    behaviour: Behaviour,
    stop: &AtomicBool,
    read: &AtomicU64,
) -> Result<ClientResult, String> {
    let mut socket = retry(stop, "the Foxglove client could not connect", || open(addr))?;
    subscribe_all(&mut socket)?;
    if behaviour == Behaviour::Stall {
        // Connected and subscribed; it never reads again, so its socket fills.
        while !stop.load(Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(50));
        }
        return Ok(ClientResult::Foxglove(behaviour, 0));
    }
    let started = Instant::now();
    let mut messages = 0;
    while !stop.load(Ordering::Relaxed) {
        if behaviour == Behaviour::Drop && started.elapsed() >= DROP_AFTER {
            // Torn down mid-stream, without a close handshake.
            let _ = socket.get_ref().shutdown(std::net::Shutdown::Both);
            break;
        }
        match socket.read() {
            Ok(Message::Binary(data)) if data.first() == Some(&1) => {
                messages += 1;
                if behaviour == Behaviour::Read {
                    read.store(messages, Ordering::Relaxed);
                }
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            // The viewer closed the connection: the run is over.
            Err(tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed) => break,
            Err(e) => return Err(format!("the reading Foxglove client lost its connection: {e}")),
        }
    }
    Ok(ClientResult::Foxglove(behaviour, messages))
}

fn open(addr: SocketAddr) -> Result<Socket, String> {
    let stream = TcpStream::connect_timeout(&addr, Duration::from_secs(2)).map_err(|e| e.to_string())?;
    let _ = stream.set_read_timeout(Some(Duration::from_millis(100)));
    let mut request = format!("ws://{addr}").into_client_request().map_err(|e| e.to_string())?;
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        tungstenite::http::HeaderValue::from_static("foxglove.sdk.v1, foxglove.websocket.v1"),
    );
    let (socket, _) = tungstenite::client(request, stream).map_err(|e| e.to_string())?;
    Ok(socket)
}

/// Reads the server's advertisements and subscribes to every channel.
fn subscribe_all(socket: &mut Socket) -> Result<(), String> {
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut ids = Vec::new();
    while ids.is_empty() {
        if Instant::now() > deadline {
            return Err("the viewer advertised no channel within 10 s".into());
        }
        match socket.read() {
            Ok(Message::Text(text)) => {
                let value: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
                if value["op"] == "advertise" {
                    ids.extend(value["channels"].as_array().into_iter().flatten().filter_map(|c| c["id"].as_u64()));
                }
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => return Err(e.to_string()),
        }
    }
    let subscriptions: Vec<serde_json::Value> =
        ids.iter().enumerate().map(|(i, id)| serde_json::json!({ "id": i, "channelId": id })).collect();
    let subscribe = serde_json::json!({ "op": "subscribe", "subscriptions": subscriptions });
    socket.send(Message::text(subscribe.to_string())).map_err(|e| e.to_string())
}

fn zenoh_client(endpoint: &Endpoint, namespace: &str, stop: &AtomicBool) -> Result<ClientResult, String> {
    let bench = retry(stop, "the Zenoh subscriber could not connect", || {
        RemoteBench::connect(endpoint, namespace).map_err(|e| e.to_string())
    })?;
    let mut tap = bench.subscribe_all(8192).map_err(|e| e.to_string())?;
    while !stop.load(Ordering::Relaxed) {
        let _ = tap.recv_timeout(Duration::from_millis(100));
    }
    let received = tap.counts().iter().map(|c| c.received).sum();
    let gaps = tap.counts().iter().map(|c| c.gaps).sum();
    Ok(ClientResult::Zenoh(received, gaps))
}
