//! The Foxglove WebSocket server: its address, its clients, its channels.

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use foxglove::websocket::{Capability, ChannelView, Client, ServerListener};
use foxglove::{Context, WebSocketServer, WebSocketServerHandle};

use crate::{BenchChannels, ViewerError};

/// Where the viewer listens unless told otherwise: this machine only.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// How long [`FoxgloveServer::stop`] waits for the clients to take their close.
pub const STOP_WAIT: std::time::Duration = std::time::Duration::from_secs(1);

/// How the server is set up.
#[derive(Clone, Debug)]
pub struct ServerOptions {
    /// Name shown by the Foxglove app.
    pub name: String,
    /// Messages queued per client before its oldest are dropped (the SDK's
    /// message backlog). 4096 is about 3 s of every channel of the bench.
    pub backlog: usize,
    /// Advertise the server's clock ([`FoxgloveServer::broadcast_time`]), for playback.
    pub time: bool,
}

impl Default for ServerOptions {
    fn default() -> Self {
        ServerOptions { name: "jetbench".into(), backlog: 4096, time: false }
    }
}

/// Clients seen by the server so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClientCounts {
    /// Clients that connected.
    pub connected: u64,
    /// Clients that have disconnected since.
    pub disconnected: u64,
    /// Channel subscriptions the clients made.
    pub subscriptions: u64,
}

/// Counts and logs clients coming and going.
#[derive(Default)]
struct ClientLog {
    connected: AtomicU64,
    disconnected: AtomicU64,
    subscriptions: AtomicU64,
}

impl ServerListener for ClientLog {
    fn on_client_connect(&self) {
        let n = self.connected.fetch_add(1, Ordering::Relaxed) + 1;
        tracing::info!("Foxglove client connected ({n} so far)");
    }

    fn on_client_disconnect(&self) {
        self.disconnected.fetch_add(1, Ordering::Relaxed);
        tracing::info!("Foxglove client disconnected");
    }

    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        self.subscriptions.fetch_add(1, Ordering::Relaxed);
        tracing::debug!("client {:?} subscribed to {}", client.id(), channel.topic());
    }
}

/// A running Foxglove WebSocket server with every bus channel advertised.
pub struct FoxgloveServer {
    handle: Option<WebSocketServerHandle>,
    /// The server holds its context weakly: without this, clients would see no channel.
    _context: Arc<Context>,
    channels: BenchChannels,
    clients: Arc<ClientLog>,
    addr: SocketAddr,
}

impl FoxgloveServer {
    /// Listens on `listen` (`HOST:PORT`; port 0 picks a free one) and
    /// advertises every bus channel.
    pub fn start(listen: &str, options: &ServerOptions) -> Result<FoxgloveServer, ViewerError> {
        Self::start_with_services(listen, options, Vec::new())
    }

    /// [`FoxgloveServer::start`], offering `services` to the clients (JSON requests).
    pub fn start_with_services(
        listen: &str,
        options: &ServerOptions,
        services: Vec<foxglove::websocket::service::Service>,
    ) -> Result<FoxgloveServer, ViewerError> {
        let addr = parse_listen(listen)?;
        // A context of its own: the channels of this server only.
        let context = Context::new();
        let channels = BenchChannels::advertise(&context)?;
        let clients = Arc::new(ClientLog::default());
        let mut server = WebSocketServer::new()
            .name(options.name.clone())
            .bind(addr.ip().to_string(), addr.port())
            .context(&context)
            .message_backlog_size(options.backlog.max(1))
            .listener(clients.clone());
        let mut capabilities = Vec::new();
        if options.time {
            capabilities.push(Capability::Time);
        }
        if !services.is_empty() {
            capabilities.push(Capability::Services);
            server = server.services(services).supported_encodings(["json"]);
        }
        if !capabilities.is_empty() {
            server = server.capabilities(capabilities);
        }
        let handle = server.start_blocking().map_err(|source| ViewerError::Start { addr: listen.into(), source })?;
        let addr = SocketAddr::new(addr.ip(), handle.port());
        Ok(FoxgloveServer { handle: Some(handle), _context: context, channels, clients, addr })
    }

    /// The address clients connect to (with the port picked, if 0 was asked).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// `ws://HOST:PORT`, what the Foxglove app opens.
    pub fn url(&self) -> String {
        format!("ws://{}", self.addr)
    }

    /// The channels the server advertises, by bus channel.
    pub fn channels(&self) -> &BenchChannels {
        &self.channels
    }

    /// The clients seen so far.
    pub fn clients(&self) -> ClientCounts {
        ClientCounts {
            connected: self.clients.connected.load(Ordering::Relaxed),
            disconnected: self.clients.disconnected.load(Ordering::Relaxed),
            subscriptions: self.clients.subscriptions.load(Ordering::Relaxed),
        }
    }

    /// Tells the clients the time being shown, ns since the Unix epoch.
    pub fn broadcast_time(&self, unix_ns: u64) {
        if let Some(handle) = &self.handle {
            handle.broadcast_time(unix_ns);
        }
    }

    /// Makes every client start afresh (a recording that starts over).
    pub fn clear_session(&self) {
        if let Some(handle) = &self.handle {
            handle.clear_session(None);
        }
    }

    /// Closes every connection and waits until they are closed, at most
    /// [`STOP_WAIT`]: a client that never reads cannot take its close, and
    /// its connection goes with the process (once; later calls do nothing).
    pub fn stop(&mut self) {
        let Some(handle) = self.handle.take() else { return };
        let shutdown = handle.stop();
        let (done, closed) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            shutdown.wait_blocking();
            let _ = done.send(());
        });
        if closed.recv_timeout(STOP_WAIT).is_err() {
            tracing::warn!("a Foxglove client did not take its close within {STOP_WAIT:?}; its connection is dropped");
        }
    }
}

/// `HOST:PORT` with an IPv4 or IPv6 address (`[::1]:8765`) or `localhost`.
pub fn parse_listen(listen: &str) -> Result<SocketAddr, ViewerError> {
    let error = |reason: &str| ViewerError::Address { addr: listen.into(), reason: reason.into() };
    let (host, port) = listen.rsplit_once(':').ok_or_else(|| error("no port"))?;
    let port: u16 = port.parse().map_err(|_| error("the port is not a number from 0 to 65535"))?;
    let host = host.trim_start_matches('[').trim_end_matches(']');
    let ip: IpAddr = match host {
        "localhost" => IpAddr::from([127, 0, 0, 1]),
        _ => host.parse().map_err(|_| error("the host is not an IP address"))?,
    };
    Ok(SocketAddr::new(ip, port))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listen_addresses_parse_or_say_why_not() {
        assert_eq!(parse_listen("0.0.0.0:8765").unwrap(), "0.0.0.0:8765".parse().unwrap());
        assert_eq!(parse_listen("[::1]:0").unwrap(), "[::1]:0".parse().unwrap());
        assert_eq!(parse_listen("localhost:9").unwrap(), "127.0.0.1:9".parse().unwrap());
        for bad in ["8765", "127.0.0.1:99999", "bench-pc:8765", ":80x"] {
            let e = parse_listen(bad).unwrap_err().to_string();
            assert!(e.contains("HOST:PORT"), "{bad}: {e}");
        }
    }
}
