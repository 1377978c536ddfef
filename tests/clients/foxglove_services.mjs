// An independent caller of a Foxglove WebSocket server's services for the jetbench
// tests, on @foxglove/ws-protocol and ws: no jetbench code is involved.
//
// node foxglove_services.mjs ws://127.0.0.1:8765 [SERVICE[=JSON] | sleep=MS ...] [--wait-s 5]
//
// Connects, waits for the server's services, prints one JSON line
// {"services": [names...]}, then calls each SERVICE in turn (the request JSON given,
// `{}` if none) and prints one JSON line per call:
// {"service": NAME, "response": text} or {"service": NAME, "failure": message}
// (a service the server does not offer: {"service": NAME, "failure": "not offered"}).
// `sleep=MS` waits MS milliseconds before the next call (a client that keeps calling
// a heartbeat service, then falls silent); it prints nothing.
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const argv = process.argv.slice(2);
const url = argv.shift();
let waitS = 5;
const calls = [];
for (let i = 0; i < argv.length; i++) {
  if (argv[i] === "--wait-s") waitS = Number(argv[++i]);
  else {
    const at = argv[i].indexOf("=");
    calls.push(at < 0 ? { name: argv[i], body: "{}" } : { name: argv[i].slice(0, at), body: argv[i].slice(at + 1) });
  }
}

const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
const services = new Map();
const waiting = new Map(); // callId -> resolve
let nextCallId = 1;
let started = false;

function call(service, body) {
  return new Promise((resolve) => {
    const callId = nextCallId++;
    waiting.set(callId, resolve);
    client.sendServiceCallRequest({
      serviceId: service.id,
      callId,
      encoding: "json",
      data: new TextEncoder().encode(body),
    });
    setTimeout(() => {
      if (waiting.delete(callId)) resolve({ failure: "no response within 10 s" });
    }, 10000);
  });
}

async function run() {
  console.log(JSON.stringify({ services: [...services.keys()].sort() }));
  for (const { name, body } of calls) {
    if (name === "sleep") {
      await new Promise((resolve) => setTimeout(resolve, Number(body)));
      continue;
    }
    const service = services.get(name);
    const result = service ? await call(service, body) : { failure: "not offered" };
    console.log(JSON.stringify({ service: name, ...result }));
  }
  process.exit(0);
}

client.on("advertiseServices", (advertised) => {
  for (const s of advertised) services.set(s.name, s);
  // The server advertises its services once, right after its info.
  if (!started) {
    started = true;
    setTimeout(run, 200);
  }
});
client.on("serviceCallResponse", ({ callId, data }) => {
  const resolve = waiting.get(callId);
  if (!waiting.delete(callId)) return;
  resolve({ response: new TextDecoder().decode(data) });
});
client.on("serviceCallFailure", ({ callId, message }) => {
  const resolve = waiting.get(callId);
  if (!waiting.delete(callId)) return;
  resolve({ failure: message });
});
client.on("error", (e) => console.error(`error: ${e?.message ?? e}`));
// A server with no services advertises none: report that after the wait.
setTimeout(() => {
  if (!started) {
    started = true;
    run();
  }
}, waitS * 1000);
