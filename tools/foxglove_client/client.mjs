// A Foxglove WebSocket client made of the packages the Foxglove app is built on:
// @foxglove/ws-protocol (the protocol), @foxglove/rosmsg (ros2msg schemas) and
// @foxglove/rosmsg2-serialization (CDR). The force tester's tests and benchmarks run it against
// monitor_node; it prints one JSON object per line on stdout.
//
//   node client.mjs --url ws://127.0.0.1:8765 --topics /force_corrected,/pull_score
//        [--until /pull_score=3] [--keep /force_corrected=200] [--timeout 60]
//        [--stall] [--malformed] [--get-params] [--set-param NAME=JSON] [--legacy]
//
// Lines: {"kind":"open","protocol":...}, {"kind":"serverInfo",...}, {"kind":"channel",...} per
// advertised channel, {"kind":"message","topic":...,"logTime":...,"data":{...}} per decoded
// message (at most --keep per topic; all are counted), {"kind":"status",...},
// {"kind":"done","counts":{...}} at the end. --until: stop once each topic has that many
// messages. --stall: subscribe, then stop reading the socket (a viewer that hangs) until killed.
// --malformed: send messages the protocol does not know before subscribing.
// --get-params: ask for every parameter (as the Parameters panel does), print
// {"kind":"parameters",...} and stop. --set-param: set one parameter (JSON value), subscribe to
// its updates, print each {"kind":"parameters",...}, and stop once it has the value that was set.
// --legacy: offer only the protocol's old name, FoxgloveClient's own default (foxglove.websocket.v1), as
// Foxglove Studio 1.48 and older Lichtblick do; without it the client offers foxglove.sdk.v1.
import rosmsg from "@foxglove/rosmsg";
import rosmsg2 from "@foxglove/rosmsg2-serialization";
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

// the three @foxglove packages are CommonJS: their named exports come from the default one
const { parse } = rosmsg;
const { MessageReader } = rosmsg2;
const { FoxgloveClient } = wsProtocol;

const SUBPROTOCOL = "foxglove.sdk.v1";

function args(argv) {
  const out = { topics: [], until: {}, keep: {}, timeout: 60, stall: false, malformed: false };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => argv[++i];
    if (a === "--url") out.url = next();
    else if (a === "--topics") out.topics = next().split(",").filter(Boolean);
    else if (a === "--until" || a === "--keep") {
      for (const kv of next().split(",")) {
        const [k, v] = kv.split("=");
        out[a.slice(2)][k] = Number(v);
      }
    } else if (a === "--timeout") out.timeout = Number(next());
    else if (a === "--stall") out.stall = true;
    else if (a === "--malformed") out.malformed = true;
    else if (a === "--get-params") out.getParams = true;
    else if (a === "--legacy") out.legacy = true;
    else if (a === "--set-param") {
      const s = next();
      const k = s.indexOf("=");
      out.setParam = { name: s.slice(0, k), value: JSON.parse(s.slice(k + 1)) };
    }
    else throw new Error(`unknown argument ${a}`);
  }
  if (!out.url) throw new Error("--url is required");
  return out;
}

function plain(value) {
  // decoded CDR -> JSON: typed arrays as arrays, bigints as numbers, NaN as the string "NaN"
  if (typeof value === "bigint") return Number(value);
  if (typeof value === "number") return Number.isFinite(value) ? value : String(value);
  if (ArrayBuffer.isView(value)) return Array.from(value, plain);
  if (Array.isArray(value)) return value.map(plain);
  if (value && typeof value === "object") {
    const o = {};
    for (const [k, v] of Object.entries(value)) o[k] = plain(v);
    return o;
  }
  return value;
}

const say = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

const opt = args(process.argv.slice(2));
const ws = new WebSocket(opt.url, [opt.legacy ? FoxgloveClient.SUPPORTED_SUBPROTOCOL : SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const readers = new Map(); // channel id -> {topic, reader}
const subscriptions = new Map(); // subscription id -> channel id
const counts = {};
let finished = false;

function finish(code) {
  if (finished) return;
  finished = true;
  client.close();
  // exit once everything written so far has reached the pipe
  process.stdout.write(JSON.stringify({ kind: "done", counts }) + "\n", () => process.exit(code));
}

setTimeout(() => finish(opt.stall ? 0 : 3), opt.timeout * 1000);

client.on("open", () => {
  say({ kind: "open", protocol: ws.protocol });
  if (opt.malformed) {
    ws.send("{this is not json");
    ws.send(JSON.stringify({ op: "noSuchOperation", x: 1 }));
    ws.send(Buffer.from([0xff, 1, 2, 3]));
  }
});
client.on("error", (err) => {
  say({ kind: "error", message: String(err && err.message ? err.message : err) });
});
client.on("close", (ev) => {
  say({ kind: "close", code: ev && ev.code });
  if (!finished) finish(4);
});
client.on("serverInfo", (info) => {
  say({ kind: "serverInfo", name: info.name, capabilities: info.capabilities });
  if (opt.getParams) client.getParameters([], "get");
  if (opt.setParam) {
    client.subscribeParameterUpdates([opt.setParam.name]);
    client.setParameters([opt.setParam], "set");
  }
});
client.on("parameterValues", (ev) => {
  const parameters = plain(ev.parameters);
  say({ kind: "parameters", id: ev.id, parameters });
  if (opt.getParams && ev.id === "get") finish(0);
  const want = opt.setParam;
  if (want && parameters.some((p) => p.name === want.name && JSON.stringify(p.value) === JSON.stringify(want.value)))
    finish(0);
});
client.on("status", (st) => say({ kind: "status", level: st.level, message: st.message }));
client.on("advertise", (channels) => {
  for (const ch of channels) {
    say({ kind: "channel", id: ch.id, topic: ch.topic, encoding: ch.encoding, schemaName: ch.schemaName,
          schemaEncoding: ch.schemaEncoding });
    if (!opt.topics.includes(ch.topic)) continue;
    if (ch.encoding !== "cdr" || ch.schemaEncoding !== "ros2msg") {
      say({ kind: "error", message: `${ch.topic}: encoding ${ch.encoding}/${ch.schemaEncoding}` });
      continue;
    }
    const definitions = parse(ch.schema, { ros2: true });
    readers.set(ch.id, { topic: ch.topic, reader: new MessageReader(definitions) });
    subscriptions.set(client.subscribe(ch.id), ch.id);
  }
  if (opt.stall && readers.size === opt.topics.length) {
    ws._socket.pause(); // read nothing more: the server's queue for us fills
    say({ kind: "stalled" });
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const id = subscriptions.get(subscriptionId);
  const r = readers.get(id);
  if (!r) return;
  counts[r.topic] = (counts[r.topic] || 0) + 1;
  const keep = opt.keep[r.topic] ?? Infinity;
  if (counts[r.topic] <= keep) {
    const decoded = r.reader.readMessage(data);
    say({ kind: "message", topic: r.topic, logTime: Number(timestamp), data: plain(decoded) });
  }
  const until = Object.entries(opt.until);
  if (until.length && until.every(([t, n]) => (counts[t] || 0) >= n)) finish(0);
});
