// An independent Foxglove WebSocket client for the jetbench tests, built on
// the npm packages @foxglove/ws-protocol, ws, @foxglove/rosmsg and
// @foxglove/rosmsg2-serialization: no jetbench code is involved.
//
// node foxglove_client.mjs ws://127.0.0.1:8765 --topics /bench/thrust,/bench/state --out got.json
//     [--behave read|stall|drop] [--drop-after-s 3] [--max-s 120]
//
// read:  subscribes, decodes every message with the advertised schema, and at
//        the end (server gone, SIGTERM, or --max-s) writes JSON to --out:
//        {"channels": {topic: advertised channel}, "messages": {topic: [fields]}, "errors": [...]}
//        uint64 fields are strings (JSON numbers cannot hold them exactly); each
//        message also has `_log_time_ns`, the timestamp the server sent with it.
// stall: subscribes, then never reads again (the socket is paused).
// drop:  subscribes, reads, and after --drop-after-s tears the TCP connection down mid-stream.
// Prints "subscribed" once every topic is subscribed.
import { writeFileSync } from "node:fs";
import wsProtocol from "@foxglove/ws-protocol";
import rosmsg from "@foxglove/rosmsg";
import rosmsg2 from "@foxglove/rosmsg2-serialization";
import WebSocket from "ws";

// CommonJS packages: named exports through their default export.
const { FoxgloveClient } = wsProtocol;
const { parse } = rosmsg;
const { MessageReader } = rosmsg2;

function options(argv) {
  const o = { url: argv[0], topics: [], out: null, behave: "read", dropAfterS: 3, maxS: 120 };
  for (let i = 1; i < argv.length; i += 2) {
    const [key, value] = [argv[i], argv[i + 1]];
    if (key === "--topics") o.topics = value.split(",");
    else if (key === "--out") o.out = value;
    else if (key === "--behave") o.behave = value;
    else if (key === "--drop-after-s") o.dropAfterS = Number(value);
    else if (key === "--max-s") o.maxS = Number(value);
    else throw new Error(`unknown option ${key}`);
  }
  if (!o.url || o.topics.length === 0) throw new Error("usage: foxglove_client.mjs URL --topics T1,T2 [--out FILE]");
  return o;
}

// JSON-safe: bigints as strings, typed arrays as arrays.
function plain(value) {
  if (typeof value === "bigint") return value.toString();
  if (ArrayBuffer.isView(value)) return Array.from(value, plain);
  if (Array.isArray(value)) return value.map(plain);
  if (value !== null && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
}

const o = options(process.argv.slice(2));
// The SDK's server speaks foxglove.sdk.v1; the npm client names foxglove.websocket.v1.
const ws = new WebSocket(o.url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
const channels = {};
const readers = new Map(); // subscription id -> { topic, reader }
const messages = Object.fromEntries(o.topics.map((t) => [t, []]));
const errors = [];
let finished = false;

function finish(why) {
  if (finished) return;
  finished = true;
  if (o.out) {
    writeFileSync(o.out, JSON.stringify({ why, channels, messages, errors }));
  }
  process.exit(0);
}

client.on("error", (e) => errors.push(`error: ${e?.message ?? e}`));
client.on("close", () => finish("closed"));
client.on("advertise", (advertised) => {
  for (const channel of advertised) {
    if (!o.topics.includes(channel.topic) || channels[channel.topic]) continue;
    channels[channel.topic] = channel;
    try {
      const definitions = parse(channel.schema, { ros2: true });
      const id = client.subscribe(channel.id);
      readers.set(id, { topic: channel.topic, reader: new MessageReader(definitions) });
    } catch (e) {
      errors.push(`${channel.topic}: ${e.message}`);
    }
    if (Object.keys(channels).length === o.topics.length) {
      console.log("subscribed");
      if (o.behave === "stall") ws._socket.pause();
      if (o.behave === "drop") setTimeout(() => ws._socket.destroy(), o.dropAfterS * 1000);
    }
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const sub = readers.get(subscriptionId);
  if (!sub) return;
  try {
    messages[sub.topic].push({ ...plain(sub.reader.readMessage(data)), _log_time_ns: String(timestamp) });
  } catch (e) {
    if (errors.length < 20) errors.push(`${sub.topic}: cannot decode ${data.byteLength} bytes: ${e.message}`);
  }
});
process.on("SIGTERM", () => finish("SIGTERM"));
process.on("SIGINT", () => finish("SIGINT"));
setTimeout(() => finish("max-s"), o.maxS * 1000);
