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
//! - a Zenoh subscriber of every channel, reading everything;
//! - an operator's client commanding the bench: over Zenoh with TLS and a
//!   client certificate ([`RoomPki`], made for the run), it takes control and
//!   then sends a heartbeat every [`COMMAND_PERIOD`], timing each answer. Each
//!   heartbeat goes the whole command path: the gateway's access control, a
//!   sample on `bench/operator`, the control service's decision, its event,
//!   the answer.
//!
//! The Foxglove clients speak the WebSocket protocol (`foxglove.sdk.v1`) with
//! a plain WebSocket library; they decode only the binary message header.

use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use jetbench_bridge::operator::{ClientTls, OperatorLink};
use jetbench_bridge::{Endpoint, RemoteBench};
use serde::Serialize;
use tungstenite::client::IntoClientRequest;
use tungstenite::Message;

/// How long a client keeps trying to reach a service that is still starting.
const CONNECT_FOR: Duration = Duration::from_secs(30);
/// How long the dropping client reads before it cuts its connection.
const DROP_AFTER: Duration = Duration::from_secs(3);
/// How often the operator's client sends a command (a heartbeat).
pub const COMMAND_PERIOD: Duration = Duration::from_millis(100);
/// The operator the client commands as: its certificate's common name.
pub const OPERATOR: &str = "control-room";

/// What the clients did.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ControlRoomReport {
    /// Messages the reading Foxglove client received.
    pub foxglove_read: u64,
    /// True when the stalled client connected and subscribed.
    pub foxglove_stalled: bool,
    /// Messages the dropping client read before it cut its connection.
    pub foxglove_dropped_after: u64,
    /// Samples the Zenoh subscriber received, and the `seq` gaps among them.
    pub zenoh_received: u64,
    /// `seq` gaps among the Zenoh subscriber's samples (samples it lost).
    pub zenoh_gaps: u64,
    /// What the operator's commanding client did.
    pub commands: CommandReport,
    /// What went wrong, per client (empty when all worked).
    pub errors: Vec<String>,
}

/// What the operator's client did: control taken over TLS, then a heartbeat every
/// [`COMMAND_PERIOD`], each answer timed.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CommandReport {
    /// True once the bench accepted its `take`.
    pub took_control: bool,
    /// Heartbeats sent after the take.
    pub sent: u64,
    /// Answered `accepted`.
    pub accepted: u64,
    /// Answered `refused: ...`.
    pub refused: u64,
    /// Answered without a decision, or not at all, while the set was up (an accepted
    /// answer came later).
    pub unanswered: u64,
    /// Not answered at the end, after the last accepted one: the set going down.
    pub unanswered_at_end: u64,
    /// The first answer that was not `accepted`, if any.
    pub first_problem: Option<String>,
    /// From sending a heartbeat to its answer, ms: p50.
    pub answer_ms_p50: f64,
    /// p99 of the same.
    pub answer_ms_p99: f64,
    /// The longest.
    pub answer_ms_max: f64,
    /// Heartbeats sent later than a period after the one before (the client itself
    /// was held up: the machine is loaded).
    pub late_sends: u64,
    /// Commands the control service recorded on `bench/operator` from this operator
    /// (counted by the campaign from the recording).
    pub recorded: u64,
    /// `COMMAND_ACCEPTED` events for them in the recording.
    pub recorded_accepted: u64,
    /// `DEADMAN` events in the recording (0 while the heartbeats keep up).
    pub deadman_events: u64,
}

/// The control room's own certificates, made with `openssl` for one run: a CA, the
/// bench's certificate (for `127.0.0.1`) and the operator's client certificate (common
/// name [`OPERATOR`]), all in one folder.
#[derive(Clone, Debug)]
pub struct RoomPki {
    /// The CA (PEM) that signed both certificates.
    pub ca: std::path::PathBuf,
    /// The bench's certificate and key (PEM).
    pub bench: (std::path::PathBuf, std::path::PathBuf),
    /// The operator's client certificate and key (PEM).
    pub operator: (std::path::PathBuf, std::path::PathBuf),
}

impl RoomPki {
    /// Makes the CA and the two certificates in `dir` (created if missing). Needs the
    /// `openssl` command; the error says what failed.
    pub fn make(dir: &std::path::Path) -> Result<RoomPki, String> {
        let openssl = crate::pki::Openssl::in_dir(dir)?;
        openssl.ca("ca", "jetbench latency control-room CA")?;
        openssl.leaf("bench", "bench", "ca", "IP:127.0.0.1")?;
        openssl.leaf("operator", OPERATOR, "ca", "DNS:control-room")?;
        Ok(RoomPki {
            ca: dir.join("ca.crt"),
            bench: (dir.join("bench.crt"), dir.join("bench.key")),
            operator: (dir.join("operator.crt"), dir.join("operator.key")),
        })
    }

    /// The `[operator]` section of a bench that trusts this PKI's operator, listening
    /// for operators at `tls_listen` (`tls/127.0.0.1:PORT`).
    pub fn settings(&self, tls_listen: &str) -> jetbench_control::operator::OperatorSettings {
        jetbench_control::operator::OperatorSettings {
            tls_listen: tls_listen.into(),
            certificate: self.bench.0.clone(),
            private_key: self.bench.1.clone(),
            client_ca: self.ca.clone(),
            operators: vec![OPERATOR.into()],
            deadman_window_s: 1.0,
            handover_offer_s: 30.0,
            foxglove_token: None,
            foxglove_operator_bind: None,
        }
    }

    fn client(&self) -> ClientTls {
        ClientTls { ca: self.ca.clone(), certificate: self.operator.0.clone(), private_key: self.operator.1.clone() }
    }
}

/// Where the operator's client commands: the bench's TLS endpoint and the PKI.
#[derive(Clone, Debug)]
pub struct Commanding {
    /// The bench's `[operator] tls_listen`.
    pub endpoint: Endpoint,
    /// The certificates the bench trusts.
    pub pki: RoomPki,
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
    Commands(CommandReport),
}

impl ControlRoom {
    /// Starts the clients of a service set that serves Foxglove at `foxglove`
    /// and Zenoh at `zenoh`, in bus namespace `namespace`. With `cpus`, each
    /// client (and every thread it starts) runs only there: the clients stand
    /// for another computer, so they are kept off the control chain's core. With
    /// `commanding`, the operator's client commands the bench too.
    pub fn attach(
        foxglove: SocketAddr,
        zenoh: Endpoint,
        namespace: String,
        cpus: Vec<usize>,
        commanding: Option<Commanding>,
    ) -> ControlRoom {
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
        if let Some(commanding) = commanding {
            let (flag, pin, namespace) = (Arc::clone(&stop), pin(), namespace.clone());
            threads.push(std::thread::spawn(move || {
                pin();
                operator_client(&commanding, &namespace, &flag)
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
                Ok(Ok(ClientResult::Commands(commands))) => report.commands = commands,
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

/// The operator's client: connects over TLS, takes control (retrying until the bench
/// answers), then sends a heartbeat every [`COMMAND_PERIOD`] until stopped, timing each
/// answer. Its link sends no heartbeats of its own: these are the commands.
fn operator_client(commanding: &Commanding, namespace: &str, stop: &AtomicBool) -> Result<ClientResult, String> {
    let tls = commanding.pki.client();
    let connect = || {
        OperatorLink::connect(&commanding.endpoint, Some(&tls), namespace, Some(OPERATOR)).map_err(|e| e.to_string())
    };
    let mut link = retry(stop, "the operator's client could not connect", connect)?;
    link.heartbeat_every(None);
    let mut report = CommandReport::default();
    // The set may still be starting: retry the take until the control service answers.
    let took = retry(stop, "the operator's client could not take control", || {
        match link.send("take", None).map_err(|e| e.to_string())? {
            answer if answer == "accepted" => Ok(()),
            answer => Err(answer),
        }
    });
    if let Err(e) = took {
        return if stop.load(Ordering::Relaxed) { Ok(ClientResult::Commands(report)) } else { Err(e) };
    }
    report.took_control = true;
    let mut answers_ms = Vec::new();
    // Not answered since the last accepted one: counted as mid-run only if an
    // accepted answer follows (else the set was going down).
    let mut pending_failures = 0;
    let mut next = Instant::now() + COMMAND_PERIOD;
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now < next {
            std::thread::sleep(next - now);
            continue;
        }
        if now > next + COMMAND_PERIOD {
            report.late_sends += 1;
            next = now;
        }
        next += COMMAND_PERIOD;
        let sent = Instant::now();
        let answer = link.send("heartbeat", None);
        report.sent += 1;
        match answer {
            Ok(a) if a == "accepted" => {
                answers_ms.push(sent.elapsed().as_secs_f64() * 1e3);
                report.accepted += 1;
                report.unanswered += pending_failures;
                pending_failures = 0;
            }
            Ok(a) if a.starts_with("refused") => {
                report.refused += 1;
                report.first_problem.get_or_insert(a);
            }
            other => {
                pending_failures += 1;
                if report.first_problem.is_none() {
                    report.first_problem = Some(match other {
                        Ok(a) => a,
                        Err(e) => e.to_string(),
                    });
                }
            }
        }
    }
    report.unanswered_at_end = pending_failures;
    if report.unanswered == 0 && report.refused == 0 {
        // Only the set going down was not answered: not a problem of the run.
        report.first_problem = None;
    }
    answers_ms.sort_by(f64::total_cmp);
    let at = |q: f64| answers_ms.get(((answers_ms.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(0.0);
    (report.answer_ms_p50, report.answer_ms_p99) = (at(0.5), at(0.99));
    report.answer_ms_max = answers_ms.last().copied().unwrap_or(0.0);
    Ok(ClientResult::Commands(report))
}
