// A Foxglove WebSocket client as the Foxglove app is one: the protocol's own client
// (@foxglove/ws-protocol) over `ws`, every advertised channel subscribed (those advertised
// later too), every message decoded from its `ros2msg` schema with Foxglove's own CDR
// reader (@foxglove/rosmsg, @foxglove/rosmsg2-serialization). It also tries what a viewer
// must not be able to do: publish a message into the server and set a parameter.
//
// Usage: node foxglove_client.js ws://HOST:PORT SECONDS
// Prints one JSON line: the server's name and capabilities, and per topic the schema,
// the messages received and decoded, the decoding errors, the rate (messages per
// second between the first and last) and one decoded sample's field names.
"use strict";

const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");
const WebSocket = require("ws");

const [url, secondsText] = process.argv.slice(2);
const seconds = Number(secondsText || "5");

const summary = {
  server: null,
  capabilities: null,
  connected: false,
  topics: {},
  publishRefused: null,
  error: null,
};
const readers = new Map(); // channel id -> { topic, reader }
const subscriptions = new Map(); // subscription id -> channel id

function finish() {
  for (const t of Object.values(summary.topics)) {
    t.rate = t.received > 1 ? (t.received - 1) / ((t.last - t.first) / 1000) : 0;
    delete t.first;
    delete t.last;
  }
  console.log(JSON.stringify(summary));
  process.exit(0);
}

// The Foxglove SDK's server (as foxglove_bridge 3.x) names the protocol `foxglove.sdk.v1`:
// `foxglove.websocket.v1` under its new name (the client takes whichever the socket
// negotiated since ws-protocol 0.7.5).
const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
client.on("error", (e) => {
  summary.error = String(e && e.message ? e.message : e);
});
client.on("open", () => {
  summary.connected = true;
});
client.on("serverInfo", (info) => {
  summary.server = info.name;
  summary.capabilities = info.capabilities;
  // A viewer that tries to publish: the server did not advertise clientPublish, so it
  // must ignore (or refuse) the channel and its message.
  try {
    const id = client.advertise({
      topic: "/posestream/heatmaps",
      encoding: "cdr",
      schemaName: "posestream_msgs/msg/HeatMaps",
    });
    client.sendMessage(id, new Uint8Array([0, 1, 0, 0, 1, 2, 3, 4]));
    client.setParameters([{ name: "estimator.window.lag", value: 0 }]);
    summary.publishRefused = "sent (the server must drop it)";
  } catch (e) {
    summary.publishRefused = String(e && e.message ? e.message : e);
  }
});
client.on("advertise", (channels) => {
  for (const c of channels) {
    const entry = (summary.topics[c.topic] = summary.topics[c.topic] || {
      schema: c.schemaName,
      encoding: c.encoding,
      schemaEncoding: c.schemaEncoding,
      received: 0,
      decoded: 0,
      errors: 0,
      firstError: null,
      fields: null,
      first: 0,
      last: 0,
    });
    try {
      const definitions = parse(c.schema, { ros2: true });
      readers.set(c.id, { topic: c.topic, reader: new MessageReader(definitions) });
    } catch (e) {
      entry.firstError = entry.firstError || `schema: ${e.message}`;
      readers.set(c.id, { topic: c.topic, reader: null });
    }
    subscriptions.set(client.subscribe(c.id), c.id);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const channelId = subscriptions.get(subscriptionId);
  const r = readers.get(channelId);
  if (!r) return;
  const t = summary.topics[r.topic];
  const now = Date.now();
  if (t.received === 0) t.first = now;
  t.last = now;
  t.received += 1;
  if (!r.reader) {
    t.errors += 1;
    return;
  }
  try {
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    const m = r.reader.readMessage(bytes);
    t.decoded += 1;
    if (!t.fields) t.fields = Object.keys(m);
  } catch (e) {
    t.errors += 1;
    t.firstError = t.firstError || e.message;
  }
});
client.on("close", () => {
  finish();
});
setTimeout(finish, seconds * 1000);
