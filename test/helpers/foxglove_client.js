// A third-party Foxglove WebSocket client for the tests: @foxglove/ws-protocol's FoxgloveClient
// over the `ws` package, decoding every message as the Foxglove app does for ros2msg channels
// (@foxglove/rosmsg parses the schema, @foxglove/rosmsg2-serialization reads the CDR).
//   node foxglove_client.js URL TOPIC:COUNT...
// Subscribes to every advertised TOPIC; prints one JSON line per event (the negotiated
// subprotocol, the advertised channels, each decoded message) and exits 0 once every TOPIC has
// delivered its COUNT messages; exits 1 on an error.
const WebSocket = require("ws");
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");

const [url, ...wanted] = process.argv.slice(2);
const counts = new Map(wanted.map((arg) => [arg.slice(0, arg.lastIndexOf(":")),
                                            Number(arg.slice(arg.lastIndexOf(":") + 1))]));
// foxglove-sdk's server speaks `foxglove.sdk.v1`; this client library's constant still names the
// older `foxglove.websocket.v1`, which the server refuses: offer both, the server picks.
const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const channels = new Map();   // subscription id -> { topic, reader }
const received = new Map([...counts.keys()].map((topic) => [topic, 0]));
const say = (event) => process.stdout.write(JSON.stringify(event) + "\n");

const stampOf = (message) => {
  const stamp = message.header?.stamp ?? message.transforms?.[0]?.header?.stamp;
  return stamp === undefined ? null : String(BigInt(stamp.sec) * 1000000000n + BigInt(stamp.nanosec));
};

client.on("open", () => say({ event: "open", protocol: ws.protocol }));
client.on("error", (error) => { say({ event: "error", message: String(error) }); process.exit(1); });
client.on("serverInfo", (info) => say({ event: "serverInfo", name: info.name }));
client.on("advertise", (advertised) => {
  for (const channel of advertised) {
    say({ event: "channel", topic: channel.topic, encoding: channel.encoding,
          schemaName: channel.schemaName, schemaEncoding: channel.schemaEncoding });
    if (!received.has(channel.topic)) continue;
    const reader = new MessageReader(parse(channel.schema, { ros2: true }));
    const id = client.subscribe(channel.id);
    channels.set(id, { topic: channel.topic, reader });
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const { topic, reader } = channels.get(subscriptionId);
  const message = reader.readMessage(data);
  const event = { event: "message", topic, logTime: String(timestamp), stamp: stampOf(message) };
  if (message.transforms) event.frames = message.transforms.map((t) => [t.header.frame_id, t.child_frame_id]);
  if (message.name) event.names = message.name;
  if (message.position) event.position = Array.from(message.position);
  if (typeof message.data === "string") event.length = message.data.length;
  if (message.linear_acceleration) event.linear_acceleration = message.linear_acceleration;
  say(event);
  received.set(topic, received.get(topic) + 1);
  if ([...counts].every(([t, n]) => received.get(t) >= n)) { ws.close(); process.exit(0); }
});
