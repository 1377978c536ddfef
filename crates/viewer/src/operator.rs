//! Operator commands as Foxglove services: a panel's button calls `jetbench/stop`, the
//! viewer publishes an `OperatorCommand` on `bench/operator` and answers with the control
//! service's decision.
//!
//! The safe commands (`stop`, `estop`, `hold`, `idle`) are always offered. The ones that
//! can make the engine run (`start`, `run`, `reference`, `clear`, `take`, `release`,
//! `handover`, `heartbeat`) are offered only when the bench config has an `[operator]`
//! section with a Foxglove token and the viewer is bound to its `foxglove_operator_bind`
//! address (the operator's network). A call carrying that token (`{"token": "..."}`) is
//! forwarded with the operator's authority; any other call with anyone's, so the control
//! service refuses what raises the engine and records it.
//!
//! Requests are JSON: `{"value": 60, "token": "..."}`, both optional. Answers are JSON:
//! `{"answer": "accepted"}`, `{"answer": "refused: ..."}`, or `{"answer": "forwarded: ..."}`
//! when no decision came within [`DECISION_TIMEOUT`].

use std::net::SocketAddr;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender};
use foxglove::websocket::service::{Request, Responder, Service, ServiceSchema};
use foxglove::Schema;
use jetbench_control::operator::{Awaiting, AwaitingDecision, OperatorSettings};
use jetbench_msgs::{authorities, operator_commands as c, origins, Event, OperatorCommand};

/// How long a call waits for the control service's decision.
pub const DECISION_TIMEOUT: Duration = Duration::from_millis(500);

/// Calls queued between the server's threads and the viewer's pump; beyond, refused.
const QUEUE: usize = 64;

/// The commands always offered.
pub const SAFE_SERVICES: &[(&str, i32)] =
    &[("stop", c::STOP), ("estop", c::STOP_NOW), ("hold", c::HOLD), ("idle", c::IDLE)];

/// The commands offered to the operator's viewer only.
pub const OPERATOR_SERVICES: &[(&str, i32)] = &[
    ("start", c::START),
    ("run", c::RUN_PROFILE),
    ("reference", c::SET_REFERENCE),
    ("clear", c::CLEAR_TRIPS),
    ("take", c::TAKE_CONTROL),
    ("release", c::RELEASE_CONTROL),
    ("handover", c::HANDOVER),
    ("heartbeat", c::HEARTBEAT),
];

/// `jetbench/<command>`: the service's name.
pub fn service_name(command: &str) -> String {
    format!("jetbench/{command}")
}

/// The token that gives a call the operator's authority, when this viewer (bound to
/// `listen`) is the operator's: the config's `foxglove_token`, if its
/// `foxglove_operator_bind` is `listen`.
pub fn operator_token(settings: Option<&OperatorSettings>, listen: SocketAddr) -> Option<String> {
    let s = settings?;
    let bind: SocketAddr = s.foxglove_operator_bind.as_deref()?.parse().ok()?;
    (bind == listen).then(|| s.foxglove_token.clone()).flatten()
}

/// A call taken from the server, waiting for the viewer's pump.
struct Call {
    command: i32,
    request: Request,
    responder: Responder,
}

/// The services' side of the gateway: what the server calls.
struct Handler {
    command: i32,
    calls: Sender<Call>,
}

impl foxglove::websocket::service::Handler for Handler {
    fn call(&self, request: Request, responder: Responder) {
        if let Err(e) = self.calls.try_send(Call { command: self.command, request, responder }) {
            let call = e.into_inner();
            call.responder.respond_err("refused: the viewer's command queue is full; call again".into());
        }
    }
}

/// The viewer's command gateway: the services to offer, the bus publisher, the calls
/// waiting for a decision.
pub struct FoxgloveGateway {
    token: Option<String>,
    calls: Receiver<Call>,
    publisher: jetbench_bus::Publisher<OperatorCommand>,
    pending: AwaitingDecision<Responder>,
    next_client_id: u32,
    offered: Vec<String>,
}

impl FoxgloveGateway {
    /// The gateway and the services to give the server: the safe ones, and with `token`
    /// (see [`operator_token`]) the operator's too.
    pub fn open(
        bus: &jetbench_bus::Bus,
        token: Option<String>,
    ) -> Result<(FoxgloveGateway, Vec<Service>), jetbench_bus::PortError> {
        let (tx, calls) = crossbeam_channel::bounded(QUEUE);
        let mut offered_commands: Vec<(&str, i32)> = SAFE_SERVICES.to_vec();
        if token.is_some() {
            offered_commands.extend_from_slice(OPERATOR_SERVICES);
        }
        let schema = service_schema;
        let services: Vec<Service> = offered_commands
            .iter()
            .map(|&(name, command)| {
                Service::builder(service_name(name), schema()).handler(Handler { command, calls: tx.clone() })
            })
            .collect();
        let offered = offered_commands.iter().map(|(n, _)| service_name(n)).collect();
        let publisher = bus.publisher(jetbench_msgs::channels::OPERATOR)?;
        let gateway = FoxgloveGateway {
            token,
            calls,
            publisher,
            pending: AwaitingDecision::new(origins::FOXGLOVE),
            next_client_id: 1,
            offered,
        };
        Ok((gateway, services))
    }

    /// The names of the services offered.
    pub fn offered(&self) -> &[String] {
        &self.offered
    }

    /// Forwards the calls queued now to the bus.
    pub fn forward(&mut self, now_ns: u64) {
        while let Ok(Call { command, request, responder }) = self.calls.try_recv() {
            let (value, token) = match parse(request.payload()) {
                Ok(parsed) => parsed,
                Err(why) => {
                    responder.respond_err(format!("refused: {why}"));
                    continue;
                }
            };
            let operator = self.token.is_some() && token.is_some() && token == self.token;
            let (authority, identity) = if operator {
                (authorities::OPERATOR, "foxglove:operator".to_string())
            } else {
                (authorities::ANYONE, format!("foxglove:client-{}", u32::from(request.client_id())))
            };
            let client_id = self.next_client_id;
            self.next_client_id = self.next_client_id.wrapping_add(1).max(1);
            let sample = OperatorCommand {
                stamp_ns: now_ns,
                publish_ns: now_ns,
                value,
                command,
                origin: origins::FOXGLOVE,
                client_id,
                authority,
                identity: jetbench_msgs::identity(&identity),
                ..Default::default()
            };
            match self.publisher.publish(sample) {
                Ok(seq) => {
                    tracing::info!(
                        "{} from {identity} forwarded as bench/operator seq {seq}",
                        c::name(command).unwrap_or("?")
                    );
                    let deadline_ns = now_ns + DECISION_TIMEOUT.as_nanos() as u64;
                    self.pending.push(Awaiting { client_id, command, deadline_ns, reply: responder });
                }
                Err(e) => responder.respond_err(format!("refused: the bench's bus did not take the command: {e}")),
            }
        }
    }

    /// Answers the call an event decides.
    pub fn decided(&mut self, event: &Event) {
        if let Some((a, accepted)) = self.pending.decided(event) {
            let answer = if accepted {
                "accepted".to_string()
            } else {
                format!("refused: {}", jetbench_control::operator::refusal_text(event.previous, a.command))
            };
            respond(a.reply, &answer);
        }
    }

    /// Answers the calls whose decision did not come by `now_ns`.
    pub fn expire(&mut self, now_ns: u64) {
        for a in self.pending.expired(now_ns) {
            let answer = format!(
                "forwarded: {} published on bench/operator; no decision from the control service within {} ms",
                c::name(a.command).unwrap_or("?"),
                DECISION_TIMEOUT.as_millis()
            );
            respond(a.reply, &answer);
        }
    }
}

/// The services' request (`{"value": N}`, optional) and answer
/// (`{"answer": "accepted ..." | "refused: ..."}`), as JSON schemas: a client
/// that builds its request form or decodes the answer from the schema
/// (Lichtblick's Call Service panel does) finds both.
fn service_schema() -> ServiceSchema {
    let json_schema = |name: &str, text: &str| Schema::new(name, "jsonschema", text.as_bytes().to_vec());
    ServiceSchema::new("jetbench/OperatorCommand")
        .with_request(
            "json",
            json_schema(
                "jetbench/OperatorCommand_Request",
                r#"{"type":"object","properties":{"value":{"type":"number","description":"the command's value (a hold's throttle cap in %, a reference in N); most commands take none"}}}"#,
            ),
        )
        .with_response(
            "json",
            json_schema(
                "jetbench/OperatorCommand_Response",
                r#"{"type":"object","properties":{"answer":{"type":"string","description":"accepted, or refused with the reason"}}}"#,
            ),
        )
}

fn respond(responder: Responder, answer: &str) {
    responder.respond_ok(serde_json::json!({ "answer": answer }).to_string());
}

/// `{"value": number, "token": "..."}`, both optional; an empty payload is `{}`.
fn parse(payload: &[u8]) -> Result<(f64, Option<String>), String> {
    if payload.iter().all(u8::is_ascii_whitespace) {
        return Ok((0.0, None));
    }
    let v: serde_json::Value =
        serde_json::from_slice(payload).map_err(|e| format!("the request is not JSON ({e}); send {{\"value\": N}}"))?;
    let value = match &v["value"] {
        serde_json::Value::Null => 0.0,
        n => n.as_f64().filter(|x| x.is_finite()).ok_or_else(|| format!("value {n} is not a finite number"))?,
    };
    Ok((value, v["token"].as_str().map(str::to_owned)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_parse_or_say_why_not() {
        assert_eq!(parse(b""), Ok((0.0, None)));
        assert_eq!(parse(b"{}"), Ok((0.0, None)));
        assert_eq!(parse(br#"{"value": 60, "token": "t"}"#), Ok((60.0, Some("t".into()))));
        assert!(parse(b"stop").unwrap_err().contains("not JSON"));
        assert!(parse(br#"{"value": "x"}"#).unwrap_err().contains("not a finite number"));
    }

    #[test]
    fn the_token_counts_only_on_the_operators_address() {
        let mut s = OperatorSettings {
            tls_listen: "tls/0.0.0.0:7448".into(),
            certificate: "b.crt".into(),
            private_key: "b.key".into(),
            client_ca: "ca.crt".into(),
            operators: vec!["alice".into()],
            deadman_window_s: 1.0,
            handover_offer_s: 30.0,
            foxglove_token: Some("0123456789abcdef".into()),
            foxglove_operator_bind: Some("10.0.0.5:8765".into()),
        };
        let at = |a: &str| a.parse::<SocketAddr>().unwrap();
        assert_eq!(operator_token(Some(&s), at("10.0.0.5:8765")).as_deref(), Some("0123456789abcdef"));
        assert_eq!(operator_token(Some(&s), at("0.0.0.0:8765")), None);
        assert_eq!(operator_token(Some(&s), at("10.0.0.5:8766")), None);
        assert_eq!(operator_token(None, at("10.0.0.5:8765")), None);
        s.foxglove_token = None;
        assert_eq!(operator_token(Some(&s), at("10.0.0.5:8765")), None);
    }
}
