//! The Zenoh bridge: the bench's channels between machines.
//!
//! On the bench PC a bridge process reads every bus channel (polled, on its
//! own clock, like the recorder) and publishes each sample under the key
//! `jetbench/<namespace>/<channel>`, e.g. `jetbench/default/bench/thrust`,
//! the payload being the sample's CDR message: exactly the MCAP message data
//! (`00 01 00 00` plus the struct bytes), encoding `application/cdr` with the
//! schema name `jetbench_msgs/msg/<Type>`. Any Zenoh client, in any language,
//! decodes it with the recorded schema. On another machine, [`RemoteBench`]
//! subscribes to those keys and checks every payload.
//!
//! ```no_run
//! use jetbench_bridge::{Endpoint, RemoteBench};
//! use jetbench_msgs::channels;
//!
//! # fn main() -> Result<(), jetbench_bridge::BridgeError> {
//! let bench = RemoteBench::connect(&"tcp/192.0.2.10:7447".parse::<Endpoint>()?, "default")?;
//! let mut thrust = bench.subscribe(channels::THRUST, 256)?;
//! while let Some(sample) = thrust.recv_timeout(std::time::Duration::from_secs(1)) {
//!     println!("{:.1} N", sample.thrust_n);
//! }
//! # Ok(())
//! # }
//! ```
//!
//! Sessions are configured explicitly: peer mode, only the endpoints given,
//! no multicast scouting and no gossip, so nothing connects that was not asked to.
#![doc = include_str!("../README.md")]

pub mod operator;
mod publish;
mod remote;
mod service;

pub use publish::{Bridge, BridgeReport};
pub use remote::{
    decode_payload, record_remote, ChannelCounts, PayloadError, RemoteBench, RemoteRecordReport, RemoteSample,
    RemoteSubscriber, RemoteTap,
};
pub use service::ZenohBridge;

use std::fmt;
use std::str::FromStr;

/// First chunk of every key the bridge publishes.
pub const KEY_PREFIX: &str = "jetbench";
/// The namespace of a bus without `JETBENCH_BUS`.
pub const DEFAULT_NAMESPACE: &str = "default";

/// Why the bridge or a remote session failed.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// An endpoint that is not `tcp/HOST:PORT` or `tls/HOST:PORT`.
    #[error("invalid Zenoh endpoint {endpoint:?}: {reason}")]
    Endpoint {
        /// The endpoint as given.
        endpoint: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Zenoh refused a setting of the session's configuration.
    #[error("invalid Zenoh setting {key}: {source}")]
    Config {
        /// The configuration key.
        key: &'static str,
        /// What Zenoh said.
        source: zenoh::Error,
    },
    /// A session that could not be opened: which endpoint, what Zenoh said (without its
    /// source locations), what to check.
    #[error("cannot open a Zenoh session {role} {endpoint}: {reason}; {hint}")]
    Open {
        /// `listening on` or `connecting to`.
        role: &'static str,
        /// The endpoint.
        endpoint: Endpoint,
        /// What Zenoh said, without its source locations.
        reason: String,
        /// What to check.
        hint: &'static str,
    },
    /// A publisher, subscriber or queryable could not be declared.
    #[error("cannot declare {what} on {key}: {source}")]
    Declare {
        /// What was declared.
        what: &'static str,
        /// On which key expression.
        key: String,
        /// What Zenoh said.
        source: zenoh::Error,
    },
    /// A channel name the bench does not have.
    #[error("unknown channel {0:?}; channels are: {names}", names = jetbench_msgs::channel_names().join(", "))]
    UnknownChannel(String),
    /// The `[operator]` settings are unusable (certificates, names, lease).
    #[error(transparent)]
    Operator(#[from] jetbench_control::operator::OperatorSettingsError),
    /// A command the bench did not answer, or that cannot be sent.
    #[error("{0}")]
    Command(String),
    /// The local bus could not be opened or used.
    #[error(transparent)]
    Bus(#[from] jetbench_bus::BusError),
    /// The bridge's recording could not be written.
    #[error(transparent)]
    Record(#[from] jetbench_record::RecordError),
}

jetbench_bus::from_bus_errors!(BridgeError);

/// Where the bridge listens unless told: this machine only.
pub const DEFAULT_ENDPOINT: &str = "tcp/127.0.0.1:7447";

/// A Zenoh endpoint, `tcp/HOST:PORT` or `tls/HOST:PORT`: where a bridge listens
/// (`tcp/0.0.0.0:7447`) or a remote tool connects (`tcp/192.0.2.10:7447`). TLS is the
/// operator's path (`[operator] tls_listen`, client certificates required).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Endpoint(String);

impl FromStr for Endpoint {
    type Err = BridgeError;

    fn from_str(s: &str) -> Result<Endpoint, BridgeError> {
        let error = |reason: &str| BridgeError::Endpoint { endpoint: s.into(), reason: reason.into() };
        let address = s.strip_prefix("tcp/").or_else(|| s.strip_prefix("tls/")).ok_or_else(|| {
            error("expected tcp/HOST:PORT (or tls/HOST:PORT for the operator), e.g. tcp/0.0.0.0:7447")
        })?;
        let (host, port) = address.rsplit_once(':').ok_or_else(|| error("no port: expected tcp/HOST:PORT"))?;
        if host.is_empty() {
            return Err(error("no host: expected tcp/HOST:PORT"));
        }
        port.parse::<u16>().map_err(|_| error("the port is not a number from 0 to 65535"))?;
        if address.contains(['#', '?']) {
            return Err(error("no #options or ?metadata: TLS files come from the config's [operator] section"));
        }
        zenoh::config::EndPoint::from_str(s).map_err(|e| error(&e.to_string()))?;
        Ok(Endpoint(s.into()))
    }
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// `jetbench/<namespace>/<channel>`, e.g. `jetbench/default/bench/thrust`.
pub fn key_for(namespace: &str, channel: &str) -> String {
    format!("{KEY_PREFIX}/{namespace}/{channel}")
}

/// Which side of a connection a session takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    /// Waits for remote peers on the endpoint (the bridge).
    Listen,
    /// Connects to the endpoint, failing if nothing answers (remote tools).
    Connect,
}

impl Role {
    fn describe(self) -> &'static str {
        match self {
            Role::Listen => "listening on",
            Role::Connect => "connecting to",
        }
    }
}

impl Endpoint {
    /// Whether it is a TLS endpoint.
    pub fn is_tls(&self) -> bool {
        self.0.starts_with("tls/")
    }
}

/// Opens a peer session on one endpoint, with nothing found by scouting.
fn open_session(role: Role, endpoint: &Endpoint) -> Result<zenoh::Session, BridgeError> {
    open_session_with(role, std::slice::from_ref(endpoint), &[])
}

/// Opens a peer session on `endpoints` (listened on or connected to), with nothing
/// found by scouting, and `extra` settings (key, JSON5 value) on top.
fn open_session_with(
    role: Role,
    endpoints: &[Endpoint],
    extra: &[(&'static str, String)],
) -> Result<zenoh::Session, BridgeError> {
    use zenoh::Wait;
    let mut config = zenoh::Config::default();
    let endpoint = endpoints.first().cloned().unwrap_or_else(|| Endpoint(DEFAULT_ENDPOINT.into()));
    let endpoints = serde_json::to_string(&endpoints.iter().map(|e| e.0.as_str()).collect::<Vec<_>>())
        .unwrap_or_else(|_| "[]".into());
    let (listen, connect) = match role {
        Role::Listen => (endpoints.as_str(), "[]"),
        Role::Connect => ("[]", endpoints.as_str()),
    };
    let settings = [
        ("mode", "\"peer\""),
        ("scouting/multicast/enabled", "false"),
        ("scouting/gossip/enabled", "false"),
        ("listen/endpoints", listen),
        ("connect/endpoints", connect),
        // A bench that does not answer is an error, not a silent retry forever.
        ("connect/timeout_ms", "5000"),
        ("connect/exit_on_failure", "true"),
    ];
    for (key, value) in settings.iter().copied().chain(extra.iter().map(|(k, v)| (*k, v.as_str()))) {
        config.insert_json5(key, value).map_err(|source| BridgeError::Config { key, source })?;
    }
    zenoh::open(config).wait().map_err(|e| BridgeError::Open {
        role: role.describe(),
        reason: zenoh_reason(&e),
        hint: match role {
            Role::Connect => {
                "check that the bench runs `jetbench up --zenoh` on that address and port, that this machine \
                 reaches it (ping, firewall), and for tls/ that the certificates are the ones the bench trusts"
            }
            Role::Listen => "check that the address is this machine's and that nothing else uses the port",
        },
        endpoint,
    })
}

/// Zenoh's error text without the source locations it appends (`at /path/to/src.rs:12.`),
/// each sentence once.
fn zenoh_reason(e: &zenoh::Error) -> String {
    let mut parts: Vec<String> = Vec::new();
    for line in e.to_string().lines() {
        let mut text = line.trim().to_string();
        while let Some(at) = text.find(" at /") {
            let end = text[at..].find(".rs:").map(|i| at + i + 4).unwrap_or(text.len());
            let digits = text[end..].chars().take_while(|c| c.is_ascii_digit() || *c == ':').count();
            let mut cut = end + digits;
            if text[cut..].starts_with('.') {
                cut += 1;
            }
            text.replace_range(at..cut, "");
        }
        let text = text.trim().trim_end_matches('.').to_string();
        if !text.is_empty() && !parts.contains(&text) {
            parts.push(text);
        }
    }
    if parts.is_empty() {
        "Zenoh gave no reason".into()
    } else {
        parts.join(": ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_tcp_with_a_port() {
        assert!("tcp/0.0.0.0:7447".parse::<Endpoint>().is_ok());
        assert!("tcp/[::1]:7447".parse::<Endpoint>().is_ok());
        assert!("tcp/bench-pc.local:7447".parse::<Endpoint>().is_ok());
        assert!("tls/10.0.0.1:7448".parse::<Endpoint>().is_ok_and(|e| e.is_tls()));
        assert!(!"tcp/10.0.0.1:7447".parse::<Endpoint>().unwrap().is_tls());
        for bad in ["udp/0.0.0.0:7447", "0.0.0.0:7447", "tcp/0.0.0.0", "tcp/:7447", "tcp/h:port", "quic/h:7447"] {
            let e = bad.parse::<Endpoint>().unwrap_err().to_string();
            assert!(e.contains("tcp/"), "{bad}: {e}");
        }
    }

    #[test]
    fn zenoh_errors_lose_their_source_paths_and_repeats() {
        let e: zenoh::Error = "Unable to connect to any of [tcp/192.0.2.1:7447]! at /root/.cargo/registry/src/i/zenoh-1.10.2/src/net/runtime/orchestrator.rs:412.\nUnable to connect to any of [tcp/192.0.2.1:7447]! at /root/.cargo/registry/src/i/zenoh-1.10.2/src/net/runtime/orchestrator.rs:377."
            .into();
        assert_eq!(zenoh_reason(&e), "Unable to connect to any of [tcp/192.0.2.1:7447]!");
        let plain: zenoh::Error = "refused".into();
        assert_eq!(zenoh_reason(&plain), "refused");
    }

    #[test]
    fn keys_name_namespace_and_channel() {
        assert_eq!(key_for("default", "bench/thrust"), "jetbench/default/bench/thrust");
    }
}
