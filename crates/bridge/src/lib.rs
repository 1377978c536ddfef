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
    #[error("invalid Zenoh endpoint {endpoint:?}: {reason}")]
    Endpoint { endpoint: String, reason: String },
    #[error("invalid Zenoh setting {key}: {source}")]
    Config { key: &'static str, source: zenoh::Error },
    #[error("cannot open a Zenoh session {role} {endpoint}: {source}")]
    Open { role: &'static str, endpoint: Endpoint, source: zenoh::Error },
    #[error("cannot declare {what} on {key}: {source}")]
    Declare { what: &'static str, key: String, source: zenoh::Error },
    #[error("unknown channel {0:?}; channels are: {names}", names = jetbench_msgs::channel_names().join(", "))]
    UnknownChannel(String),
    #[error(transparent)]
    Bus(#[from] jetbench_bus::BusError),
    #[error(transparent)]
    Record(#[from] jetbench_record::RecordError),
}

jetbench_bus::from_bus_errors!(BridgeError);

/// Where the bridge listens unless told: this machine only.
pub const DEFAULT_ENDPOINT: &str = "tcp/127.0.0.1:7447";

/// A Zenoh TCP endpoint, `tcp/HOST:PORT`: where a bridge listens
/// (`tcp/0.0.0.0:7447`) or a remote tool connects (`tcp/192.0.2.10:7447`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Endpoint(String);

impl FromStr for Endpoint {
    type Err = BridgeError;

    fn from_str(s: &str) -> Result<Endpoint, BridgeError> {
        let error = |reason: &str| BridgeError::Endpoint { endpoint: s.into(), reason: reason.into() };
        let address = s.strip_prefix("tcp/").ok_or_else(|| {
            error("expected tcp/HOST:PORT, e.g. tcp/0.0.0.0:7447 (this build carries Zenoh over TCP only)")
        })?;
        let (host, port) = address.rsplit_once(':').ok_or_else(|| error("no port: expected tcp/HOST:PORT"))?;
        if host.is_empty() {
            return Err(error("no host: expected tcp/HOST:PORT"));
        }
        port.parse::<u16>().map_err(|_| error("the port is not a number from 0 to 65535"))?;
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

/// Opens a peer session on one endpoint, with nothing found by scouting.
fn open_session(role: Role, endpoint: &Endpoint) -> Result<zenoh::Session, BridgeError> {
    use zenoh::Wait;
    let mut config = zenoh::Config::default();
    let endpoints = format!("[\"{endpoint}\"]");
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
    for (key, value) in settings {
        config.insert_json5(key, value).map_err(|source| BridgeError::Config { key, source })?;
    }
    zenoh::open(config).wait().map_err(|source| BridgeError::Open {
        role: role.describe(),
        endpoint: endpoint.clone(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_tcp_with_a_port() {
        assert!("tcp/0.0.0.0:7447".parse::<Endpoint>().is_ok());
        assert!("tcp/[::1]:7447".parse::<Endpoint>().is_ok());
        assert!("tcp/bench-pc.local:7447".parse::<Endpoint>().is_ok());
        for bad in ["udp/0.0.0.0:7447", "0.0.0.0:7447", "tcp/0.0.0.0", "tcp/:7447", "tcp/h:port"] {
            let e = bad.parse::<Endpoint>().unwrap_err().to_string();
            assert!(e.contains("tcp/"), "{bad}: {e}");
        }
    }

    #[test]
    fn keys_name_namespace_and_channel() {
        assert_eq!(key_for("default", "bench/thrust"), "jetbench/default/bench/thrust");
    }
}
