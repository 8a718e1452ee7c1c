// Decode every message of an MCAP bag with Foxglove's own readers (@mcap/core, @foxglove/rosmsg,
// @foxglove/rosmsg2-serialization), as Foxglove Studio does. Used by
// tests/rrg_bags/test_bag_recorder.py.
// A file without its summary and index (its recorder was killed) is read as Foxglove Studio reads
// an unindexed file: streamed from the start, up to its last complete record.
//
//   node tests/foxglove_bag_reader.cjs NODE_MODULES_DIR BAG.mcap
//
// Prints one JSON object: {profile, indexed, topics: {topic: {schema, count, trailing_bytes}},
// last: {topic: message}}. Exits non-zero when a schema does not parse or a message does not decode.
"use strict";
const fs = require("fs");
const path = require("path");

const [modules, bagPath] = process.argv.slice(2);
const { McapIndexedReader, McapStreamReader } = require(path.join(modules, "@mcap/core"));
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

// The file's header, schemas, channels and messages: through its index, or streamed.
async function open(file) {
  try {
    const reader = await McapIndexedReader.Initialize({ readable: fileReadable(file) });
    return {
      indexed: true,
      header: reader.header,
      schemas: reader.schemasById,
      channels: reader.channelsById,
      messages: reader.readMessages(),
    };
  } catch (err) {
    const stream = new McapStreamReader();
    stream.append(fs.readFileSync(file));
    const found = { indexed: false, schemas: new Map(), channels: new Map(), list: [] };
    for (;;) {
      let record;
      try {
        record = stream.nextRecord();
      } catch (e) {
        break; // a truncated record: the file ends here
      }
      if (!record) break;
      if (record.type === "Header") found.header = record;
      else if (record.type === "Schema") found.schemas.set(record.id, record);
      else if (record.type === "Channel") found.channels.set(record.id, record);
      else if (record.type === "Message") found.list.push(record);
    }
    found.messages = found.list;
    return found;
  }
}

async function main() {
  const bag = await open(bagPath);
  const readers = new Map();
  const topics = {};
  const last = {};
  for (const [id, channel] of bag.channels) {
    const schema = bag.schemas.get(channel.schemaId);
    if (schema.encoding !== "ros2msg" || channel.messageEncoding !== "cdr") {
      throw new Error(`${channel.topic}: encodings ${schema.encoding}/${channel.messageEncoding}`);
    }
    const text = new TextDecoder().decode(schema.data);
    readers.set(id, new MessageReader(parse(text, { ros2: true })));
    topics[channel.topic] = { schema: schema.name, count: 0, trailing_bytes: 0 };
  }
  for await (const message of bag.messages) {
    const channel = bag.channels.get(message.channelId);
    const msgReader = readers.get(message.channelId);
    last[channel.topic] = msgReader.readMessage(message.data);
    topics[channel.topic].count += 1;
    if (msgReader.lastReadHadTrailingBytes()) topics[channel.topic].trailing_bytes += 1;
  }
  const out = { profile: bag.header.profile, indexed: bag.indexed, topics, last };
  process.stdout.write(JSON.stringify(out, plain));
}

main().catch((err) => {
  process.stderr.write(`${err.stack || err}\n`);
  process.exit(1);
});
