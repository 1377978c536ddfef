//! The environment that places a process on a bus: its namespace
//! ([`NAMESPACE_ENV`]) and its transport ([`TRANSPORT_ENV`]).

use crate::error::EnvError;

/// Environment variable that names the bus namespace. Service sets in
/// different namespaces share nothing, so a test run cannot disturb a bench
/// that is running on the same machine. Unset: the default namespace.
pub const NAMESPACE_ENV: &str = "JETBENCH_BUS";

/// Environment variable that chooses the [`Transport`] of every process of a
/// service set (`jetbench up --transport` sets it for the services it starts).
pub const TRANSPORT_ENV: &str = "JETBENCH_TRANSPORT";

/// The bus namespace from [`NAMESPACE_ENV`], checked: letters, digits, `_`
/// and `-`, at most 32 characters. `None`: the default namespace.
pub fn namespace() -> Result<Option<String>, EnvError> {
    let Ok(ns) = std::env::var(NAMESPACE_ENV) else { return Ok(None) };
    if ns.is_empty() {
        return Ok(None);
    }
    if ns.len() > 32 || !ns.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
        return Err(EnvError::Namespace { value: ns });
    }
    Ok(Some(ns))
}

/// The namespace's name as folders and keys spell it: `default` when unset.
pub fn namespace_name() -> Result<String, EnvError> {
    Ok(namespace()?.unwrap_or_else(|| "default".into()))
}

/// How samples travel between the processes of a service set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Transport {
    /// Shared in iceoryx2 shared memory, never copied (the default).
    Iceoryx2,
    /// Copied through Unix domain sockets ([`crate::uds`]): the baseline.
    UnixSockets,
}

impl Transport {
    /// `iceoryx2` or `uds`, as [`TRANSPORT_ENV`] and `--transport` spell it.
    pub fn name(self) -> &'static str {
        match self {
            Transport::Iceoryx2 => "iceoryx2",
            Transport::UnixSockets => "uds",
        }
    }
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Transport {
    type Err = EnvError;

    fn from_str(s: &str) -> Result<Self, EnvError> {
        match s {
            "iceoryx2" | "" => Ok(Transport::Iceoryx2),
            "uds" => Ok(Transport::UnixSockets),
            _ => Err(EnvError::Transport { value: s.into() }),
        }
    }
}

/// The transport [`TRANSPORT_ENV`] chooses; iceoryx2 when it is unset.
pub fn transport() -> Result<Transport, EnvError> {
    std::env::var(TRANSPORT_ENV).unwrap_or_default().parse()
}
