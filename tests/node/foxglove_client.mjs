// A Foxglove WebSocket client built on npm's @foxglove/ws-protocol (the library Lichtblick uses), as a
// viewer would be: it connects with the subprotocol given, subscribes to every advertised channel, decodes
// each message from its channel's advertised schema (protobuf from the FileDescriptorSet the server sends,
// or JSON) and prints one JSON line per message: {topic, schemaName, encoding, message}.
//
//   node foxglove_client.mjs URL SUBPROTOCOL SECONDS [TOPIC[=TEXT]...]
// Ends when every TOPIC named has had a message (one whose JSON contains TEXT, where given), or after
// SECONDS; exit 0 if connected, 3 if not.
import wsProtocol from "@foxglove/ws-protocol";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, subprotocol, seconds, ...wantedArgs] = process.argv.slice(2);
const wanted = wantedArgs.map((w) => {
  const at = w.indexOf("=");
  return at < 0 ? { topic: w, text: "" } : { topic: w.slice(0, at), text: w.slice(at + 1) };
});
const ws = new WebSocket(url, [subprotocol]);
const client = new FoxgloveClient({ ws });
const decoders = new Map(); // subscription id -> {channel, decode}
const seen = new Set();
let opened = false;

function decoderFor(channel) {
  if (channel.encoding === "json") {
    return (data) => JSON.parse(new TextDecoder().decode(data));
  }
  if (channel.encoding === "protobuf") {
    const bytes = Buffer.from(channel.schema, "base64");
    const set = descriptor.FileDescriptorSet.decode(bytes);
    const root = protobuf.Root.fromDescriptor(set);
    const type = root.lookupType(channel.schemaName);
    return (data) => type.toObject(type.decode(data), { longs: Number, bytes: String, defaults: true });
  }
  throw new Error(`unexpected encoding ${channel.encoding} on ${channel.topic}`);
}

function finish(code) {
  ws.close();
  setTimeout(() => process.exit(code), 50);
}

client.on("open", () => {
  opened = true;
  console.log(JSON.stringify({ event: "open", protocol: ws.protocol }));
});
client.on("error", (e) => console.error(`client error: ${e}`));
client.on("advertise", (channels) => {
  for (const channel of channels) {
    const id = client.subscribe(channel.id);
    decoders.set(id, { channel, decode: decoderFor(channel) });
    console.log(JSON.stringify({ event: "advertise", topic: channel.topic, schemaName: channel.schemaName,
                                 encoding: channel.encoding, schemaEncoding: channel.schemaEncoding }));
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const entry = decoders.get(subscriptionId);
  if (!entry) return;
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  const message = entry.decode(bytes);
  const line = JSON.stringify({ topic: entry.channel.topic, schemaName: entry.channel.schemaName,
                                encoding: entry.channel.encoding, message });
  console.log(line);
  wanted.forEach((w, i) => {
    if (w.topic === entry.channel.topic && line.includes(w.text)) seen.add(i);
  });
  if (wanted.length && seen.size === wanted.length) finish(0);
});
setTimeout(() => finish(opened ? 0 : 3), Number(seconds) * 1000);
