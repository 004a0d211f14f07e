// Reads an MCAP file as Foxglove does, with Foxglove's own packages (@mcap/core, @foxglove/rosmsg,
// @foxglove/rosmsg-serialization, @foxglove/rosmsg2-serialization, @foxglove/wasm-zstd), and
// prints one JSON line per message: its channel, schema and the message decoded from its native
// encoding (ros1 or cdr); json messages parsed. Byte arrays are printed as base64, other typed
// arrays as lists. Then one line per metadata record. Usage: node mcap_decode.js FILE
"use strict";
const fs = require("fs");
const { McapIndexedReader } = require("@mcap/core");
const { parse } = require("@foxglove/rosmsg");
const ros1 = require("@foxglove/rosmsg-serialization");
const ros2 = require("@foxglove/rosmsg2-serialization");
const zstd = require("@foxglove/wasm-zstd");

function plain(key, value) {
  if (typeof value === "bigint") return value.toString();
  if (typeof value === "number" && !Number.isFinite(value)) return String(value);
  if (value instanceof Uint8Array || value instanceof Int8Array) return { base64: Buffer.from(value).toString("base64") };
  if (ArrayBuffer.isView(value)) return Array.from(value);
  return value;
}

async function main() {
  await zstd.isLoaded;
  const data = fs.readFileSync(process.argv[2]);
  const readable = {
    size: async () => BigInt(data.length),
    read: async (offset, length) => data.subarray(Number(offset), Number(offset + length)),
  };
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: { zstd: (buffer, size) => zstd.decompress(buffer, Number(size)) },
  });
  const decoders = new Map();
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    const text = new TextDecoder().decode(schema.data);
    let decode;
    if (channel.messageEncoding === "ros1" && schema.encoding === "ros1msg") {
      const messageReader = new ros1.MessageReader(parse(text, { ros2: false }));
      decode = (bytes) => messageReader.readMessage(bytes);
    } else if (channel.messageEncoding === "cdr" && schema.encoding === "ros2msg") {
      const messageReader = new ros2.MessageReader(parse(text, { ros2: true }));
      decode = (bytes) => messageReader.readMessage(bytes);
    } else if (channel.messageEncoding === "json") {
      decode = (bytes) => JSON.parse(new TextDecoder().decode(bytes));
    } else {
      throw new Error(`channel ${channel.topic}: no decoder for ${channel.messageEncoding}/${schema.encoding}`);
    }
    decoders.set(id, { channel, schema, decode });
  }
  for await (const message of reader.readMessages()) {
    const { channel, schema, decode } = decoders.get(message.channelId);
    const line = {
      kind: "message",
      topic: channel.topic,
      channel_metadata: Object.fromEntries(channel.metadata),
      schema: schema.name,
      encoding: channel.messageEncoding,
      log_time: message.logTime,
      publish_time: message.publishTime,
      message: decode(message.data),
    };
    process.stdout.write(JSON.stringify(line, plain) + "\n");
  }
  for await (const metadata of reader.readMetadata()) {
    process.stdout.write(JSON.stringify({ kind: "metadata", name: metadata.name, metadata: Object.fromEntries(metadata.metadata) }) + "\n");
  }
}

main().catch((error) => {
  process.stderr.write(`${error.stack || error}\n`);
  process.exit(1);
});
