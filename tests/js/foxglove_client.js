// The official @foxglove/ws-protocol client against Shepherd's live view: connects with the
// subprotocol it offers by default (foxglove.websocket.v1, as Lichtblick and older Foxglove
// apps do), subscribes to every channel and prints one JSON line per channel once it has a
// message: {"topic", "schemaName", "encoding", "bytes", "decoded"}. Usage: node
// foxglove_client.js ws://127.0.0.1:PORT N_CHANNELS TIMEOUT_S
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, want, timeoutS] = [process.argv[2], Number(process.argv[3]), Number(process.argv[4])];
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const channels = new Map();
const done = new Set();
client.on("advertise", (list) => {
  for (const ch of list) {
    const id = client.subscribe(ch.id);
    channels.set(id, ch);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const ch = channels.get(subscriptionId);
  if (!ch || done.has(ch.topic)) return;
  done.add(ch.topic);
  let decoded = null;
  if (ch.encoding === "json") {
    decoded = JSON.parse(new TextDecoder().decode(data));
  }
  console.log(JSON.stringify({ topic: ch.topic, schemaName: ch.schemaName,
    encoding: ch.encoding, bytes: data.byteLength, decoded,
    protocol: ws.protocol }));
  if (done.size >= want) { client.close(); process.exit(0); }
});
client.on("error", (e) => { console.error(String(e)); });
setTimeout(() => { console.error(`timeout: ${[...done].join(",")}`); process.exit(1); },
  timeoutS * 1000);
