// Decode every message of an MCAP bag with Foxglove's own readers (@mcap/core, @foxglove/rosmsg,
// @foxglove/rosmsg2-serialization), as Foxglove Studio does. Used by tests/test_bag_recorder.py.
//
//   node tests/foxglove_bag_reader.cjs NODE_MODULES_DIR BAG.mcap
//
// Prints one JSON object: {profile, topics: {topic: {schema, count, trailing_bytes}}, last: {topic: message}}.
// Exits non-zero when a schema does not parse or a message does not decode.
"use strict";
const fs = require("fs");
const path = require("path");

const [modules, bagPath] = process.argv.slice(2);
const { McapIndexedReader } = require(path.join(modules, "@mcap/core"));
const { parse } = require(path.join(modules, "@foxglove/rosmsg"));
const { MessageReader } = require(path.join(modules, "@foxglove/rosmsg2-serialization"));

function fileReadable(file) {
  const fd = fs.openSync(file, "r");
  const size = BigInt(fs.fstatSync(fd).size);
  return {
    size: async () => size,
    read: async (offset, length) => {
      const buf = Buffer.alloc(Number(length));
      fs.readSync(fd, buf, 0, Number(length), Number(offset));
      return new Uint8Array(buf.buffer, buf.byteOffset, buf.byteLength);
    },
  };
}

// JSON.stringify with typed arrays as plain arrays and bigints as numbers.
function plain(_key, value) {
  if (typeof value === "bigint") return Number(value);
  if (ArrayBuffer.isView(value)) return Array.from(value);
  return value;
}

async function main() {
  const reader = await McapIndexedReader.Initialize({ readable: fileReadable(bagPath) });
  const readers = new Map();
  const topics = {};
  const last = {};
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    if (schema.encoding !== "ros2msg" || channel.messageEncoding !== "cdr") {
      throw new Error(`${channel.topic}: encodings ${schema.encoding}/${channel.messageEncoding}`);
    }
    const text = new TextDecoder().decode(schema.data);
    readers.set(id, new MessageReader(parse(text, { ros2: true })));
    topics[channel.topic] = { schema: schema.name, count: 0, trailing_bytes: 0 };
  }
  for await (const message of reader.readMessages()) {
    const channel = reader.channelsById.get(message.channelId);
    const msgReader = readers.get(message.channelId);
    last[channel.topic] = msgReader.readMessage(message.data);
    topics[channel.topic].count += 1;
    if (msgReader.lastReadHadTrailingBytes()) topics[channel.topic].trailing_bytes += 1;
  }
  process.stdout.write(JSON.stringify({ profile: reader.header.profile, topics, last }, plain));
}

main().catch((err) => {
  process.stderr.write(`${err.stack || err}\n`);
  process.exit(1);
});
