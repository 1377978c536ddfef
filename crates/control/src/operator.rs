//! The operator lease and the deadman on the control room's link, as a pure state machine.
//!
//! ```
//! use jetbench_control::operator::{Identity, Lease, LeaseSettings, LeaseChange};
//!
//! let mut lease = Lease::new(LeaseSettings::default()); // deadman window 1 s
//! let alice = Identity::new("alice")?;
//! let bob = Identity::new("bob")?;
//! let s = 1_000_000_000; // ns
//!
//! assert_eq!(lease.take(0, alice), Ok(LeaseChange::Taken { by: alice, from: None }));
//! assert!(lease.take(s / 2, bob).is_err()); // alice holds it and is alive
//! lease.heartbeat(s / 2, alice)?;
//! assert_eq!(lease.deadman(s, true), None); // heard from alice 0.5 s ago
//! let reason = lease.deadman(2 * s, true).expect("1.5 s of silence above idle");
//! assert_eq!(reason.holder, alice);
//! assert_eq!(lease.deadman(2 * s + 10, true), None); // once per silence
//! assert!(lease.take(2 * s, bob).is_ok()); // alice's link has lapsed
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! One operator at a time holds control. It is taken (`TAKE_CONTROL`) when nobody holds it
//! or the holder's link has lapsed (no heartbeat for longer than the window); it moves to
//! another operator only by a handover the holder offers and the other accepts
//! (`HANDOVER` from the holder offers it, `HANDOVER` from anyone else accepts an open
//! offer); it is given up with `RELEASE_CONTROL`. The holder's client sends `HEARTBEAT`s;
//! [`Lease::deadman`] says when the engine must go to idle because the holder has been
//! silent longer than the window while the engine runs above idle. A link that has lapsed
//! stays lapsed: heartbeats that arrive after the window (held back by an outage and
//! delivered late) are refused, and the holder takes control again, which is recorded.
//!
//! Who may send what (safe commands from anyone, raising ones only with the operator's
//! authority) is the control service's rule; this machine answers only "does this identity
//! hold control". It has no clock and no IPC: time is the caller's monotonic nanoseconds,
//! so the control service (which calls it on every command and every tick), replay and
//! tests drive it alike.

use std::fmt;

/// Longest identity, bytes (the width of the `identity` field of the bus samples).
pub const IDENTITY_LEN: usize = jetbench_msgs::IDENTITY_LEN;

/// Who sent a command: a certificate's common name, `local:<user>`, a Foxglove client, as
/// UTF-8 NUL-padded to [`IDENTITY_LEN`] bytes, exactly the bus samples' `identity` field.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Identity([u8; IDENTITY_LEN]);

/// Why a name cannot be an [`Identity`]. Names are never truncated: two long certificate
/// names sharing their first 32 bytes would otherwise become the same operator.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum IdentityError {
    /// The name is empty.
    #[error("an identity cannot be empty")]
    Empty,
    /// The name is longer than the field.
    #[error("identity {name:?} is {len} bytes; at most {IDENTITY_LEN} fit (use a shorter certificate common name)")]
    TooLong {
        /// The name.
        name: String,
        /// Its length in bytes.
        len: usize,
    },
    /// The name contains a NUL byte, which ends the field.
    #[error("identity {name:?} contains a NUL byte")]
    Nul {
        /// The name, NULs shown escaped.
        name: String,
    },
}

impl Identity {
    /// The identity named `name` (UTF-8, 1 to 32 bytes, no NUL).
    pub fn new(name: &str) -> Result<Self, IdentityError> {
        let bytes = name.as_bytes();
        if bytes.is_empty() {
            return Err(IdentityError::Empty);
        }
        if bytes.len() > IDENTITY_LEN {
            return Err(IdentityError::TooLong { name: name.to_owned(), len: bytes.len() });
        }
        if bytes.contains(&0) {
            return Err(IdentityError::Nul { name: name.to_owned() });
        }
        let mut field = [0u8; IDENTITY_LEN];
        field[..bytes.len()].copy_from_slice(bytes);
        Ok(Self(field))
    }

    /// The identity in a bus sample's field; `None` if it is empty, not UTF-8 or has bytes
    /// after its NUL padding.
    pub fn from_field(field: [u8; IDENTITY_LEN]) -> Option<Self> {
        let len = field.iter().position(|&b| b == 0).unwrap_or(IDENTITY_LEN);
        if len == 0 || field[len..].iter().any(|&b| b != 0) {
            return None;
        }
        std::str::from_utf8(&field[..len]).ok()?;
        Some(Self(field))
    }

    /// The bytes for a bus sample's `identity` field.
    pub fn field(&self) -> [u8; IDENTITY_LEN] {
        self.0
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        let len = self.0.iter().position(|&b| b == 0).unwrap_or(IDENTITY_LEN);
        // Constructed only from UTF-8 (`new`, `from_field` checks); a cut at a NUL byte
        // cannot split a multi-byte character, since NUL never occurs inside one.
        std::str::from_utf8(&self.0[..len]).unwrap_or("")
    }
}

impl fmt::Display for Identity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Debug for Identity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Identity({:?})", self.as_str())
    }
}

/// The lease's timing, from the config's `[operator]` section.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LeaseSettings {
    /// Longest silence of the holder's heartbeats before their link counts as lapsed, ns.
    pub deadman_window_ns: u64,
    /// How long a handover offer stays open, ns.
    pub handover_offer_ns: u64,
}

impl Default for LeaseSettings {
    /// A 1 s deadman window; handover offers open for 30 s.
    fn default() -> Self {
        Self { deadman_window_ns: 1_000_000_000, handover_offer_ns: 30_000_000_000 }
    }
}

/// What an accepted lease command changed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LeaseChange {
    /// `by` now holds control; `from` is the previous holder whose link had lapsed, if any.
    Taken {
        /// The new holder.
        by: Identity,
        /// The lapsed holder it was taken from.
        from: Option<Identity>,
    },
    /// The holder asked again on a live link: nothing changed but their heartbeat.
    AlreadyHeld,
    /// Nobody holds control any more.
    Released {
        /// The former holder.
        by: Identity,
    },
    /// The holder offered control to the next operator who accepts.
    Offered {
        /// The holder.
        by: Identity,
    },
    /// Control moved by an accepted handover.
    HandedOver {
        /// The former holder, who offered.
        from: Identity,
        /// The new holder, who accepted.
        to: Identity,
    },
    /// The holder's heartbeat was noted.
    Heartbeat,
}

/// Why a lease command was refused (the text goes into the refused event and the reply).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LeaseRefusal {
    /// Someone else holds control and their link is alive.
    #[error("{holder} holds control (ask them to hand over)")]
    HeldBy {
        /// The holder.
        holder: Identity,
    },
    /// The command is the holder's to send (release, heartbeat, offer).
    #[error("{who} does not hold control")]
    NotHolder {
        /// Who sent it.
        who: Identity,
    },
    /// The holder's link lapsed (silent beyond the deadman window): a heartbeat or an
    /// offer does not revive it; the holder takes control again.
    #[error("{who}'s link lapsed after {:.3} s of silence: take control again", seconds(.silent_ns))]
    Lapsed {
        /// The holder whose link lapsed.
        who: Identity,
        /// How long they had been silent, ns.
        silent_ns: u64,
    },
    /// A handover was accepted with no open offer.
    #[error("no handover is offered; {holder} holds control")]
    NoOffer {
        /// The holder.
        holder: Identity,
    },
}

/// `ns` nanoseconds in seconds, for messages.
fn seconds(ns: &u64) -> f64 {
    *ns as f64 * 1e-9
}

/// The deadman fired: the holder's link has been silent too long with the engine above
/// idle. The control service idles the engine and latches an event with this reason.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeadmanReason {
    /// Whose link lapsed.
    pub holder: Identity,
    /// How long they had been silent when it fired, ns.
    pub silent_ns: u64,
    /// The window it exceeded, ns.
    pub window_ns: u64,
}

impl fmt::Display for DeadmanReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "operator {} silent for {:.3} s (deadman window {:.3} s)",
            self.holder,
            self.silent_ns as f64 * 1e-9,
            self.window_ns as f64 * 1e-9
        )
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Holder {
    who: Identity,
    heard_ns: u64,
    offered_ns: Option<u64>,
    deadman_fired: bool,
}

/// The operator lease: who holds control, when they were last heard, an open handover.
#[derive(Clone, Debug)]
pub struct Lease {
    settings: LeaseSettings,
    holder: Option<Holder>,
}

impl Lease {
    /// A lease nobody holds.
    pub fn new(settings: LeaseSettings) -> Self {
        Self { settings, holder: None }
    }

    /// The settings it runs with.
    pub fn settings(&self) -> LeaseSettings {
        self.settings
    }

    /// Who holds control (alive or lapsed).
    pub fn holder(&self) -> Option<Identity> {
        self.holder.map(|h| h.who)
    }

    /// Whether the holder's link has lapsed at `now_ns` (`false` when nobody holds it).
    pub fn lapsed(&self, now_ns: u64) -> bool {
        self.holder.is_some_and(|h| self.silent(h, now_ns) > self.settings.deadman_window_ns)
    }

    /// Whether `who` holds control with a live link at `now_ns`: what a raising command
    /// needs on top of the operator's authority.
    pub fn in_control(&self, now_ns: u64, who: Identity) -> bool {
        self.holder.is_some_and(|h| h.who == who) && !self.lapsed(now_ns)
    }

    /// `TAKE_CONTROL` from `who` (with the operator's authority, checked by the caller):
    /// accepted when nobody holds control, the holder's link has lapsed (taken from them;
    /// by the holder themselves, taken again, `from` naming them), or `who` already holds
    /// it on a live link.
    pub fn take(&mut self, now_ns: u64, who: Identity) -> Result<LeaseChange, LeaseRefusal> {
        match self.holder {
            Some(h) if h.who == who && !self.lapsed(now_ns) => {
                self.hear(now_ns);
                Ok(LeaseChange::AlreadyHeld)
            }
            Some(h) if !self.lapsed(now_ns) => Err(LeaseRefusal::HeldBy { holder: h.who }),
            previous => {
                self.holder = Some(Holder { who, heard_ns: now_ns, offered_ns: None, deadman_fired: false });
                Ok(LeaseChange::Taken { by: who, from: previous.map(|h| h.who) })
            }
        }
    }

    /// `RELEASE_CONTROL` from `who`: only the holder gives control up.
    pub fn release(&mut self, _now_ns: u64, who: Identity) -> Result<LeaseChange, LeaseRefusal> {
        match self.holder {
            Some(h) if h.who == who => {
                self.holder = None;
                Ok(LeaseChange::Released { by: who })
            }
            _ => Err(LeaseRefusal::NotHolder { who }),
        }
    }

    /// `HEARTBEAT` from `who`: keeps the holder's live link alive. A heartbeat after the
    /// link lapsed (silent beyond the window, whether the deadman fired or not) is
    /// refused: delivered late after an outage, it must not renew the lease; the holder
    /// takes control again.
    pub fn heartbeat(&mut self, now_ns: u64, who: Identity) -> Result<LeaseChange, LeaseRefusal> {
        match self.holder {
            Some(h) if h.who == who && self.lapsed(now_ns) => {
                Err(LeaseRefusal::Lapsed { who, silent_ns: self.silent(h, now_ns) })
            }
            Some(h) if h.who == who => {
                self.hear(now_ns);
                Ok(LeaseChange::Heartbeat)
            }
            _ => Err(LeaseRefusal::NotHolder { who }),
        }
    }

    /// `HANDOVER` from `who`: from the holder it offers control (open for the settings'
    /// offer time, and only while the holder's link is alive: a lapsed holder's offer is
    /// refused); from another operator it accepts an open offer.
    pub fn handover(&mut self, now_ns: u64, who: Identity) -> Result<LeaseChange, LeaseRefusal> {
        let Some(h) = self.holder else {
            return Err(LeaseRefusal::NotHolder { who });
        };
        if h.who == who && self.lapsed(now_ns) {
            return Err(LeaseRefusal::Lapsed { who, silent_ns: self.silent(h, now_ns) });
        }
        if h.who == who {
            self.hear(now_ns);
            if let Some(holder) = self.holder.as_mut() {
                holder.offered_ns = Some(now_ns);
            }
            return Ok(LeaseChange::Offered { by: who });
        }
        if self.offer_open(h, now_ns) {
            self.holder = Some(Holder { who, heard_ns: now_ns, offered_ns: None, deadman_fired: false });
            return Ok(LeaseChange::HandedOver { from: h.who, to: who });
        }
        Err(LeaseRefusal::NoOffer { holder: h.who })
    }

    /// Whether the holder has offered a handover that is still open at `now_ns`.
    pub fn offered(&self, now_ns: u64) -> bool {
        self.holder.is_some_and(|h| self.offer_open(h, now_ns))
    }

    /// The deadman, called on every control tick: `Some(reason)` once per silence, at the
    /// first tick where the holder has been silent longer than the window while the engine
    /// runs above idle (`running_above_idle`). The caller idles the engine and latches an
    /// event with the reason. Nobody holding control arms no deadman.
    pub fn deadman(&mut self, now_ns: u64, running_above_idle: bool) -> Option<DeadmanReason> {
        let window_ns = self.settings.deadman_window_ns;
        let h = self.holder?;
        let silent_ns = self.silent(h, now_ns);
        if !running_above_idle || h.deadman_fired || silent_ns <= window_ns {
            return None;
        }
        if let Some(holder) = self.holder.as_mut() {
            holder.deadman_fired = true;
        }
        Some(DeadmanReason { holder: h.who, silent_ns, window_ns })
    }

    fn hear(&mut self, now_ns: u64) {
        if let Some(h) = self.holder.as_mut() {
            // A command stamped before the last one (clocks of two gateways) never moves
            // the heard time back.
            h.heard_ns = h.heard_ns.max(now_ns);
            h.deadman_fired = false;
        }
    }

    fn silent(&self, h: Holder, now_ns: u64) -> u64 {
        now_ns.saturating_sub(h.heard_ns)
    }

    fn offer_open(&self, h: Holder, now_ns: u64) -> bool {
        h.offered_ns.is_some_and(|at| now_ns.saturating_sub(at) <= self.settings.handover_offer_ns)
            && !self.lapsed(now_ns)
    }
}

/// The bench config's `[operator]` section: who may operate the bench from the control
/// room, and how they prove it. Absent, the bench is view-only from the network, as it
/// always was; present, the Zenoh bridge adds a TLS listener that requires a client
/// certificate, answers commands, and the viewer offers Foxglove services.
///
/// ```toml
/// [operator]
/// tls_listen = "tls/0.0.0.0:7448"            # operators connect here (client certificate required)
/// certificate = "/etc/jetbench/bench.crt"     # the bench's certificate (PEM), shown to clients
/// private_key = "/etc/jetbench/bench.key"     # its key (PEM)
/// client_ca = "/etc/jetbench/operators-ca.crt" # client certificates must chain to this CA
/// operators = ["alice.control-room"]          # certificate common names allowed to operate
/// deadman_window_s = 1.0                      # heartbeat silence that idles the engine
/// foxglove_token = "a long random string"     # the Foxglove operator's token ...
/// foxglove_operator_bind = "10.0.0.5:8765"    # ... valid only on a viewer bound here
/// ```
#[derive(Clone, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct OperatorSettings {
    /// The Zenoh TLS endpoint operators connect to, `tls/HOST:PORT`.
    pub tls_listen: String,
    /// The bench's certificate (PEM) for that listener.
    pub certificate: std::path::PathBuf,
    /// The key of [`Self::certificate`] (PEM).
    pub private_key: std::path::PathBuf,
    /// The CA (PEM) that operators' client certificates must chain to.
    pub client_ca: std::path::PathBuf,
    /// Common names of the client certificates that may operate (at most 32 bytes each).
    pub operators: Vec<String>,
    /// Longest silence of the operator's heartbeats while the engine runs above idle, s.
    #[serde(default = "default_deadman_window_s")]
    pub deadman_window_s: f64,
    /// How long a handover offer stays open, s.
    #[serde(default = "default_handover_offer_s")]
    pub handover_offer_s: f64,
    /// The token a Foxglove operator's viewer is started with (`jetbench view --operator-token`).
    #[serde(default)]
    pub foxglove_token: Option<String>,
    /// The address (`HOST:PORT`) the viewer must be bound to for the token to count: the
    /// operator's network, never `0.0.0.0`.
    #[serde(default)]
    pub foxglove_operator_bind: Option<String>,
}

fn default_deadman_window_s() -> f64 {
    1.0
}

fn default_handover_offer_s() -> f64 {
    30.0
}

/// A setting of `[operator]` that cannot work, naming the key and what is expected.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("[operator] {key}: {problem}")]
pub struct OperatorSettingsError {
    /// The key in the `[operator]` section.
    pub key: &'static str,
    /// What is wrong with it and what is expected.
    pub problem: String,
}

/// Shortest token accepted: a guessable token would give the engine to whoever guesses it.
pub const MIN_TOKEN_LEN: usize = 16;

impl OperatorSettings {
    /// Checks every setting but the files (names fit, the window is positive, the token
    /// goes with an address); the first problem found, naming its key. The config loader
    /// calls it; a recorded config replayed on another machine needs no certificates.
    pub fn check(&self) -> Result<(), OperatorSettingsError> {
        let bad = |key: &'static str, problem: String| Err(OperatorSettingsError { key, problem });
        match self.tls_listen.strip_prefix("tls/").and_then(|a| a.rsplit_once(':')) {
            Some((host, port)) if !host.is_empty() && port.parse::<u16>().is_ok() => {}
            _ => {
                return bad(
                    "tls_listen",
                    format!("{:?} is not tls/HOST:PORT (for example tls/0.0.0.0:7448)", self.tls_listen),
                )
            }
        }
        if self.operators.is_empty() {
            return bad("operators", "no operator is named; list the common names of their client certificates".into());
        }
        for (i, name) in self.operators.iter().enumerate() {
            if let Err(e) = Identity::new(name) {
                return bad("operators", format!("entry {i}: {e}"));
            }
            // The name becomes a chunk of a Zenoh key (`.../op/<name>/cmd/...`).
            if name.contains(['/', '*', '$', '?', '#']) || name.trim() != name {
                return bad(
                    "operators",
                    format!("entry {i} {name:?}: a common name with / * $ ? # or edge spaces cannot name a key"),
                );
            }
            if self.operators[..i].contains(name) {
                return bad("operators", format!("{name:?} is listed twice"));
            }
        }
        for (key, value) in [("deadman_window_s", self.deadman_window_s), ("handover_offer_s", self.handover_offer_s)] {
            if !(value.is_finite() && value > 0.0 && value <= 3600.0) {
                return bad(key, format!("{value} s; expected more than 0 and at most 3600 s"));
            }
        }
        match (&self.foxglove_token, &self.foxglove_operator_bind) {
            (None, None) => {}
            (Some(_), None) | (None, Some(_)) => {
                return bad(
                    "foxglove_token",
                    "foxglove_token and foxglove_operator_bind go together (a token is only valid on the operator's address)".into(),
                )
            }
            (Some(token), Some(bind)) => {
                if token.chars().count() < MIN_TOKEN_LEN {
                    return bad("foxglove_token", format!("too short; use at least {MIN_TOKEN_LEN} random characters"));
                }
                match bind.parse::<std::net::SocketAddr>() {
                    Ok(a) if a.ip().is_unspecified() => {
                        return bad("foxglove_operator_bind", format!("{bind} listens everywhere; give the operator network's address"))
                    }
                    Ok(_) => {}
                    Err(_) => return bad("foxglove_operator_bind", format!("{bind:?} is not IP:PORT")),
                }
            }
        }
        Ok(())
    }

    /// Checks that the certificate, key and CA files are readable PEM; the service that
    /// serves the control room calls it when it starts.
    pub fn check_files(&self) -> Result<(), OperatorSettingsError> {
        let bad = |key: &'static str, problem: String| Err(OperatorSettingsError { key, problem });
        for (key, path) in
            [("certificate", &self.certificate), ("private_key", &self.private_key), ("client_ca", &self.client_ca)]
        {
            match std::fs::read_to_string(path) {
                Ok(text) if text.contains("-----BEGIN ") => {}
                Ok(_) => return bad(key, format!("{} is not a PEM file (no -----BEGIN line)", path.display())),
                Err(e) => return bad(key, format!("cannot read {}: {e}", path.display())),
            }
        }
        Ok(())
    }

    /// Makes the relative file paths relative to `dir` (the config file's folder).
    pub fn resolve(&mut self, dir: &std::path::Path) {
        for path in [&mut self.certificate, &mut self.private_key, &mut self.client_ca] {
            if path.is_relative() {
                *path = dir.join(&*path);
            }
        }
    }

    /// The lease timing these settings give.
    pub fn lease(&self) -> LeaseSettings {
        LeaseSettings {
            deadman_window_ns: (self.deadman_window_s * 1e9).round() as u64,
            handover_offer_ns: (self.handover_offer_s * 1e9).round() as u64,
        }
    }

    /// Whether `name` (a verified certificate's common name) is an operator.
    pub fn is_operator(&self, name: &str) -> bool {
        self.operators.iter().any(|o| o == name)
    }
}

/// The commands a gateway forwarded to the bus and whose decision it waits for: the
/// control service answers each with a `COMMAND_ACCEPTED` or `COMMAND_REFUSED` event
/// naming the gateway (`origin`), the request (`source_id` = the command's `client_id`)
/// and the command (`code`). `R` is what the gateway answers through (a Zenoh query, a
/// Foxglove responder).
#[derive(Debug)]
pub struct AwaitingDecision<R> {
    origin: u32,
    items: Vec<Awaiting<R>>,
}

/// One forwarded command waiting for its decision.
#[derive(Debug)]
pub struct Awaiting<R> {
    /// The request's number, the command's `client_id`.
    pub client_id: u32,
    /// The command (`operator_commands`).
    pub command: i32,
    /// When to stop waiting (monotonic, ns).
    pub deadline_ns: u64,
    /// The answer channel.
    pub reply: R,
}

impl<R> AwaitingDecision<R> {
    /// Waiting for the decisions of commands from gateway `origin` (`origins::ZENOH`, ...).
    pub fn new(origin: u32) -> Self {
        Self { origin, items: Vec::new() }
    }

    /// Waits for the decision of a forwarded command.
    pub fn push(&mut self, awaiting: Awaiting<R>) {
        self.items.push(awaiting);
    }

    /// The command `event` decides, if it is one of ours, with `true` for accepted.
    pub fn decided(&mut self, event: &jetbench_msgs::Event) -> Option<(Awaiting<R>, bool)> {
        use jetbench_msgs::event_kinds;
        let accepted = match event.kind {
            event_kinds::COMMAND_ACCEPTED => true,
            event_kinds::COMMAND_REFUSED => false,
            _ => return None,
        };
        if event.origin != self.origin {
            return None;
        }
        let i = self.items.iter().position(|a| a.client_id == event.source_id && a.command == event.code)?;
        Some((self.items.swap_remove(i), accepted))
    }

    /// The commands whose deadline has passed at `now_ns`, no longer waited for.
    pub fn expired(&mut self, now_ns: u64) -> Vec<Awaiting<R>> {
        let (gone, kept) = std::mem::take(&mut self.items).into_iter().partition(|a| a.deadline_ns <= now_ns);
        self.items = kept;
        gone
    }

    /// How many are waiting.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether none is waiting.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }
}

/// Why the control service refused a command, in words, from the refusal code of its
/// `COMMAND_REFUSED` event (`previous`, one of `refusals`): what a gateway answers.
pub fn refusal_text(refusal: i32, command: i32) -> String {
    use jetbench_msgs::refusals as r;
    let name = jetbench_msgs::operator_commands::name(command).unwrap_or("an unknown command");
    match refusal {
        r::NOT_AUTHORISED => format!("{name} needs an authenticated operator (a trusted client certificate or token)"),
        r::NOT_NOW => format!("{name} is not possible in the engine's state now"),
        r::TEST_ENDED => "the test has ended: the engine is being brought down".into(),
        r::BAD_VALUE => format!("the value of {name} is out of range"),
        r::UNKNOWN => "the bench does not know this command".into(),
        r::TRIPPED => "trips are latched: clear them first".into(),
        r::HELD_BY_ANOTHER => "another operator holds control (ask them to hand over)".into(),
        r::NOT_IN_CONTROL => format!("{name} is for the operator in control: take control first"),
        r::NO_HANDOVER_OFFER => "no handover is offered by the operator in control".into(),
        other => format!("{name} refused by the control service (reason code {other})"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const S: u64 = 1_000_000_000;
    const MS: u64 = 1_000_000;

    fn id(name: &str) -> Identity {
        Identity::new(name).unwrap()
    }

    fn lease() -> Lease {
        Lease::new(LeaseSettings::default())
    }

    #[test]
    fn identity_round_trips_through_the_field_and_refuses_what_would_alias() {
        let a = id("operator-1.control-room");
        assert_eq!(Identity::from_field(a.field()), Some(a));
        assert_eq!(a.to_string(), "operator-1.control-room");
        let full = "x".repeat(IDENTITY_LEN);
        assert_eq!(id(&full).as_str(), full);
        assert!(matches!(Identity::new(&"x".repeat(33)), Err(IdentityError::TooLong { len: 33, .. })));
        assert_eq!(Identity::new(""), Err(IdentityError::Empty));
        assert!(matches!(Identity::new("a\0b"), Err(IdentityError::Nul { .. })));
        assert_eq!(Identity::from_field([0; IDENTITY_LEN]), None);
        let mut gap = [0u8; IDENTITY_LEN];
        gap[0] = b'a';
        gap[2] = b'b';
        assert_eq!(Identity::from_field(gap), None, "bytes after the padding");
        let mut bad = [0u8; IDENTITY_LEN];
        bad[0] = 0xff;
        assert_eq!(Identity::from_field(bad), None, "not UTF-8");
        let e = id("é");
        assert_eq!(Identity::from_field(e.field()).map(|i| i.to_string()), Some("é".into()));
    }

    #[test]
    fn take_when_free_refused_while_held_and_alive() {
        let mut l = lease();
        let (a, b) = (id("a"), id("b"));
        assert_eq!(l.take(0, a), Ok(LeaseChange::Taken { by: a, from: None }));
        assert_eq!(l.take(S, b), Err(LeaseRefusal::HeldBy { holder: a }), "exactly the window: still alive");
        assert_eq!(l.take(S / 2, a), Ok(LeaseChange::AlreadyHeld));
        assert_eq!(l.take(S + S / 2, b), Err(LeaseRefusal::HeldBy { holder: a }), "re-take refreshed a");
        assert_eq!(l.take(S + S / 2 + 1, b), Ok(LeaseChange::Taken { by: b, from: Some(a) }));
        assert_eq!(l.holder(), Some(b));
        assert!(l.in_control(S + S / 2 + 1, b));
        assert!(!l.in_control(S + S / 2 + 1, a));
    }

    #[test]
    fn release_only_by_the_holder_frees_the_lease() {
        let mut l = lease();
        let (a, b) = (id("a"), id("b"));
        assert_eq!(l.release(0, a), Err(LeaseRefusal::NotHolder { who: a }));
        l.take(0, a).unwrap();
        assert_eq!(l.release(1, b), Err(LeaseRefusal::NotHolder { who: b }));
        assert_eq!(l.release(2, a), Ok(LeaseChange::Released { by: a }));
        assert_eq!(l.holder(), None);
        assert_eq!(l.take(3, b), Ok(LeaseChange::Taken { by: b, from: None }));
    }

    #[test]
    fn handover_needs_the_holders_offer_and_expires() {
        let mut l = lease();
        let (a, b, c) = (id("a"), id("b"), id("c"));
        assert_eq!(l.handover(0, b), Err(LeaseRefusal::NotHolder { who: b }), "nobody to hand over");
        l.take(0, a).unwrap();
        assert_eq!(l.handover(MS, b), Err(LeaseRefusal::NoOffer { holder: a }));
        assert!(!l.offered(MS));
        assert_eq!(l.handover(2 * MS, a), Ok(LeaseChange::Offered { by: a }));
        assert!(l.offered(2 * MS));
        assert_eq!(l.take(3 * MS, c), Err(LeaseRefusal::HeldBy { holder: a }), "an offer is no free lease");
        assert_eq!(l.handover(4 * MS, b), Ok(LeaseChange::HandedOver { from: a, to: b }));
        assert_eq!(l.holder(), Some(b));
        assert!(!l.offered(4 * MS), "the offer is used up");
        assert_eq!(l.handover(5 * MS, c), Err(LeaseRefusal::NoOffer { holder: b }));
        assert_eq!(l.heartbeat(5 * MS, a), Err(LeaseRefusal::NotHolder { who: a }));

        // An offer closes after its time even while the holder keeps heartbeating.
        let mut l = lease();
        l.take(0, a).unwrap();
        l.handover(0, a).unwrap();
        let offer = l.settings().handover_offer_ns;
        let mut t = 0;
        while t <= offer {
            t += S / 2;
            l.heartbeat(t, a).unwrap();
        }
        assert_eq!(l.handover(t, b), Err(LeaseRefusal::NoOffer { holder: a }));

        // And when the holder's link lapses (then anyone may simply take control).
        let mut l = lease();
        l.take(0, a).unwrap();
        l.handover(0, a).unwrap();
        assert!(!l.offered(S + 1));
        assert_eq!(l.handover(S + 1, b), Err(LeaseRefusal::NoOffer { holder: a }));
        assert_eq!(l.take(S + 1, b), Ok(LeaseChange::Taken { by: b, from: Some(a) }));
    }

    #[test]
    fn deadman_fires_once_per_silence_above_idle_only() {
        let mut l = lease();
        let a = id("a");
        assert_eq!(l.deadman(10 * S, true), None, "nobody in control: no deadman");
        l.take(0, a).unwrap();
        assert_eq!(l.deadman(S, true), None, "exactly the window is not beyond it");
        assert_eq!(l.deadman(S + 1, false), None, "at idle there is nothing to stop");
        let r = l.deadman(S + 1, true).unwrap();
        assert_eq!(r, DeadmanReason { holder: a, silent_ns: S + 1, window_ns: S });
        assert!(r.to_string().contains("operator a silent for 1.000 s"), "{r}");
        assert_eq!(l.deadman(S + 2, true), None, "latched by the caller, reported once");
        assert_eq!(l.deadman(5 * S, true), None);
        // A late heartbeat does not re-arm it; taking control again does.
        assert_eq!(l.heartbeat(5 * S, a), Err(LeaseRefusal::Lapsed { who: a, silent_ns: 5 * S }));
        assert_eq!(l.take(5 * S, a), Ok(LeaseChange::Taken { by: a, from: Some(a) }));
        assert_eq!(l.deadman(6 * S, true), None);
        assert!(l.deadman(6 * S + 1, true).is_some());
        // A release disarms it (after a's link lapsed again, a takes control first).
        l.take(7 * S, a).unwrap();
        l.release(7 * S, a).unwrap();
        assert_eq!(l.deadman(20 * S, true), None);
    }

    #[test]
    fn a_stale_stamp_never_moves_the_heard_time_back() {
        let mut l = lease();
        let a = id("a");
        l.take(10 * S, a).unwrap();
        l.heartbeat(5 * S, a).unwrap();
        assert_eq!(l.deadman(11 * S, true), None);
        assert!(!l.lapsed(11 * S));
        // A clock before the take (saturating): silent 0, never lapsed.
        assert!(!l.lapsed(0));
    }

    #[test]
    fn a_different_window_is_honoured() {
        let mut l = Lease::new(LeaseSettings { deadman_window_ns: 250 * MS, handover_offer_ns: S });
        let (a, b) = (id("a"), id("b"));
        l.take(0, a).unwrap();
        assert!(l.take(250 * MS, b).is_err());
        assert!(l.deadman(250 * MS + 1, true).is_some());
        assert!(l.take(250 * MS + 1, b).is_ok());
    }

    fn settings(dir: &std::path::Path) -> OperatorSettings {
        for f in ["bench.crt", "bench.key", "ca.crt"] {
            std::fs::write(dir.join(f), "-----BEGIN CERTIFICATE-----\n").unwrap();
        }
        OperatorSettings {
            tls_listen: "tls/0.0.0.0:7448".into(),
            certificate: dir.join("bench.crt"),
            private_key: dir.join("bench.key"),
            client_ca: dir.join("ca.crt"),
            operators: vec!["alice".into()],
            deadman_window_s: 1.0,
            handover_offer_s: 30.0,
            foxglove_token: None,
            foxglove_operator_bind: None,
        }
    }

    #[test]
    fn operator_settings_name_the_key_that_is_wrong() {
        let dir = std::env::temp_dir().join(format!("jetbench-operator-settings-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = settings(&dir);
        good.check().unwrap();
        good.check_files().unwrap();
        assert_eq!(good.lease(), LeaseSettings::default());
        assert!(good.is_operator("alice") && !good.is_operator("bob"));
        let parsed: OperatorSettings = toml::from_str(&format!(
            "tls_listen = \"tls/0.0.0.0:7448\"\ncertificate = {:?}\nprivate_key = {:?}\nclient_ca = {:?}\noperators = [\"alice\"]\n",
            good.certificate, good.private_key, good.client_ca
        ))
        .unwrap();
        assert_eq!(parsed, good, "defaults: 1 s window, 30 s offers, no Foxglove operator");
        assert!(
            toml::from_str::<OperatorSettings>("tls_listen = \"x\"\nwindow = 1").is_err(),
            "unknown keys are refused"
        );

        type Edit = Box<dyn Fn(&mut OperatorSettings)>;
        let cases: Vec<(&str, Edit)> = vec![
            ("tls_listen", Box::new(|s| s.tls_listen = "tcp/0.0.0.0:7448".into())),
            ("tls_listen", Box::new(|s| s.tls_listen = "tls/0.0.0.0".into())),
            ("certificate", Box::new(|s| s.certificate = "/nonexistent/bench.crt".into())),
            ("private_key", Box::new(|s| s.private_key = std::env::temp_dir())),
            ("operators", Box::new(|s| s.operators.clear())),
            ("operators", Box::new(|s| s.operators = vec!["x".repeat(33)])),
            ("operators", Box::new(|s| s.operators = vec!["a/b".into()])),
            ("operators", Box::new(|s| s.operators = vec!["a".into(), "a".into()])),
            ("deadman_window_s", Box::new(|s| s.deadman_window_s = 0.0)),
            ("deadman_window_s", Box::new(|s| s.deadman_window_s = f64::NAN)),
            ("handover_offer_s", Box::new(|s| s.handover_offer_s = -1.0)),
            ("foxglove_token", Box::new(|s| s.foxglove_token = Some("x".repeat(MIN_TOKEN_LEN)))),
            (
                "foxglove_token",
                Box::new(|s| {
                    s.foxglove_token = Some("short".into());
                    s.foxglove_operator_bind = Some("10.0.0.5:8765".into());
                }),
            ),
            (
                "foxglove_operator_bind",
                Box::new(|s| {
                    s.foxglove_token = Some("x".repeat(MIN_TOKEN_LEN));
                    s.foxglove_operator_bind = Some("0.0.0.0:8765".into());
                }),
            ),
            (
                "foxglove_operator_bind",
                Box::new(|s| {
                    s.foxglove_token = Some("x".repeat(MIN_TOKEN_LEN));
                    s.foxglove_operator_bind = Some("operator-pc:8765".into());
                }),
            ),
        ];
        for (key, edit) in cases {
            let mut s = good.clone();
            edit(&mut s);
            let e = s.check().and_then(|()| s.check_files()).unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(e.to_string().starts_with(&format!("[operator] {key}: ")), "{e}");
        }
        std::fs::write(dir.join("bench.key"), "not pem").unwrap();
        good.check().unwrap();
        assert_eq!(good.check_files().unwrap_err().key, "private_key");
        let mut relative = good.clone();
        relative.certificate = "bench.crt".into();
        relative.resolve(&dir);
        assert_eq!(relative.certificate, dir.join("bench.crt"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn decisions_find_their_command_and_the_rest_expire() {
        use jetbench_msgs::{event_kinds, operator_commands as c, origins, Event};
        let mut w = AwaitingDecision::new(origins::ZENOH);
        for (id, command) in [(1, c::START), (2, c::STOP), (3, c::HOLD)] {
            w.push(Awaiting { client_id: id, command, deadline_ns: 100 * id as u64, reply: id });
        }
        let event = |kind, origin, source_id, code| Event { kind, origin, source_id, code, ..Default::default() };
        assert!(w.decided(&event(event_kinds::TRIP, origins::ZENOH, 1, c::START)).is_none(), "not a decision");
        assert!(
            w.decided(&event(event_kinds::COMMAND_ACCEPTED, origins::FOXGLOVE, 1, c::START)).is_none(),
            "another gateway's"
        );
        assert!(
            w.decided(&event(event_kinds::COMMAND_ACCEPTED, origins::ZENOH, 1, c::STOP)).is_none(),
            "another command"
        );
        let (a, ok) = w.decided(&event(event_kinds::COMMAND_REFUSED, origins::ZENOH, 1, c::START)).unwrap();
        assert_eq!((a.reply, ok), (1, false));
        let (a, ok) = w.decided(&event(event_kinds::COMMAND_ACCEPTED, origins::ZENOH, 2, c::STOP)).unwrap();
        assert_eq!((a.reply, ok), (2, true));
        assert!(
            w.decided(&event(event_kinds::COMMAND_ACCEPTED, origins::ZENOH, 2, c::STOP)).is_none(),
            "answered once"
        );
        assert!(w.expired(299).is_empty());
        assert_eq!(w.expired(300).iter().map(|a| a.reply).collect::<Vec<_>>(), vec![3]);
        assert!(w.is_empty());
    }

    #[derive(Clone, Copy, Debug)]
    enum Op {
        Take(usize),
        Release(usize),
        Heartbeat(usize),
        Handover(usize),
        Tick(bool),
    }

    fn op() -> impl Strategy<Value = (u64, Op)> {
        let who = 0usize..3;
        (
            0u64..1_500 * MS,
            prop_oneof![
                who.clone().prop_map(Op::Take),
                who.clone().prop_map(Op::Release),
                who.clone().prop_map(Op::Heartbeat),
                who.prop_map(Op::Handover),
                any::<bool>().prop_map(Op::Tick),
            ],
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

        /// After the deadman fired, late heartbeats from the former holder (any number, any
        /// spacing: an outage's backlog delivered at once or trickling in) never renew the
        /// lease: the link stays lapsed, raising needs control, and the deadman does not
        /// fire again. Only the holder's own take brings control back, as a take from the
        /// lapsed link, and then the deadman is armed again.
        #[test]
        fn late_heartbeats_never_revive_a_lapsed_holder(
            window_ms in 50u64..3_000,
            beyond_ms in 1u64..2_000,
            late in proptest::collection::vec(0u64..500, 1..40),
        ) {
            let settings = LeaseSettings { deadman_window_ns: window_ms * MS, handover_offer_ns: 30 * S };
            let mut l = Lease::new(settings);
            let a = id("a");
            l.take(0, a).unwrap();
            let fired_at = window_ms * MS + beyond_ms * MS;
            prop_assert!(l.deadman(fired_at, true).is_some());
            let mut now = fired_at;
            for dt in late {
                now += dt * MS;
                let r = l.heartbeat(now, a);
                prop_assert_eq!(r, Err(LeaseRefusal::Lapsed { who: a, silent_ns: now }));
                prop_assert_eq!(l.handover(now, a), Err(LeaseRefusal::Lapsed { who: a, silent_ns: now }));
                prop_assert!(l.lapsed(now) && !l.in_control(now, a));
                prop_assert_eq!(l.deadman(now, true), None, "fired once per silence");
                prop_assert_eq!(l.holder(), Some(a), "the record of who held it stays");
            }
            prop_assert_eq!(l.take(now, a), Ok(LeaseChange::Taken { by: a, from: Some(a) }));
            prop_assert!(l.in_control(now, a));
            prop_assert_eq!(l.heartbeat(now + window_ms * MS, a), Ok(LeaseChange::Heartbeat));
            prop_assert!(l.deadman(now + 2 * window_ms * MS + 1, true).is_some(), "armed again");
        }

        /// Random command sequences from three operators: one holder at most; control
        /// changes hands only by a take of a free or lapsed lease, an accepted open offer
        /// or a release; the deadman fires exactly when the holder has been silent beyond
        /// the window above idle, once per silence.
        #[test]
        fn the_lease_rules_hold_for_any_sequence(steps in proptest::collection::vec(op(), 1..80)) {
            let who = [id("a"), id("b"), id("c")];
            let window = S;
            let mut l = lease();
            let mut now = 0u64;
            // The test's own account: last heard, and whether the deadman fired since.
            let mut heard = 0u64;
            let mut fired = false;
            for (dt, op) in steps {
                now += dt;
                let before = l.holder();
                let was_lapsed = l.lapsed(now);
                let was_offered = l.offered(now);
                match op {
                    Op::Take(i) => {
                        let r = l.take(now, who[i]);
                        let may = before.is_none() || before == Some(who[i]) || was_lapsed;
                        prop_assert_eq!(r.is_ok(), may, "take by {} held by {:?}", who[i], before);
                        if may { heard = now; fired = false; }
                        if before.is_some() && before != Some(who[i]) && !was_lapsed {
                            prop_assert_eq!(r, Err(LeaseRefusal::HeldBy { holder: before.unwrap() }));
                        }
                        if before == Some(who[i]) && was_lapsed {
                            // Taken again, recorded as taken from the lapsed link.
                            prop_assert_eq!(r, Ok(LeaseChange::Taken { by: who[i], from: Some(who[i]) }));
                        }
                    }
                    Op::Release(i) => {
                        let r = l.release(now, who[i]);
                        prop_assert_eq!(r.is_ok(), before == Some(who[i]));
                    }
                    Op::Heartbeat(i) => {
                        let r = l.heartbeat(now, who[i]);
                        // Only a live link is kept alive: a heartbeat after the window
                        // (late, after an outage) never renews the lease.
                        let live = before == Some(who[i]) && now.saturating_sub(heard) <= window;
                        prop_assert_eq!(r.is_ok(), live, "heartbeat by {} at {} heard {}", who[i], now, heard);
                        if before == Some(who[i]) && !live {
                            let lapsed = matches!(r, Err(LeaseRefusal::Lapsed { .. }));
                            prop_assert!(lapsed, "a late heartbeat is refused as lapsed: {:?}", r);
                            prop_assert!(l.lapsed(now), "a refused heartbeat leaves the link lapsed");
                            prop_assert!(!l.in_control(now, who[i]));
                        }
                        if r.is_ok() { heard = now; fired = false; }
                    }
                    Op::Handover(i) => {
                        let r = l.handover(now, who[i]);
                        let ok = (before == Some(who[i]) && !was_lapsed)
                            || (before.is_some() && before != Some(who[i]) && was_offered);
                        prop_assert_eq!(r.is_ok(), ok);
                        if ok { heard = now; fired = false; }
                        if before.is_some() && before != Some(who[i]) && was_offered {
                            prop_assert_eq!(r, Ok(LeaseChange::HandedOver { from: before.unwrap(), to: who[i] }));
                        }
                        if was_offered {
                            prop_assert!(!was_lapsed, "an offer is never open on a lapsed link");
                        }
                    }
                    Op::Tick(running) => {
                        let r = l.deadman(now, running);
                        let should = before.is_some() && running && !fired && now - heard > window;
                        prop_assert_eq!(r.is_some(), should, "now {} heard {} fired {}", now, heard, fired);
                        if let Some(r) = r {
                            prop_assert_eq!(Some(r.holder), before);
                            prop_assert!(r.silent_ns > r.window_ns);
                            fired = true;
                        }
                        prop_assert_eq!(l.holder(), before, "the deadman never changes the holder");
                    }
                }
                // The holder changed only in the ways the rules allow.
                let after = l.holder();
                if after != before {
                    match (op, before, after) {
                        (Op::Take(i), None, Some(x)) => prop_assert_eq!(x, who[i]),
                        (Op::Take(i), Some(_), Some(x)) => { prop_assert!(was_lapsed); prop_assert_eq!(x, who[i]); }
                        (Op::Handover(i), Some(_), Some(x)) => { prop_assert!(was_offered); prop_assert_eq!(x, who[i]); }
                        (Op::Release(i), Some(x), None) => prop_assert_eq!(x, who[i]),
                        other => prop_assert!(false, "control moved unexpectedly: {:?}", other),
                    }
                }
                if after.is_none() { fired = false; }
            }
        }
    }
}
