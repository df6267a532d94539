// An independent MCAP reader for tests/integration/test_record.py and test_snapshot.py: @mcap/core (npm) reads the
// file named on the command line through its summary and index, decompressing zstd chunks with fzstd, and prints
// what it found as one JSON object: per channel its topic, message encoding, schema (name, encoding, parsed: JSON
// for jsonschema, the first line of a ros2msg definition), message count and whether log times never go back; the
// library and profile of the header. JSON messages must parse; CDR messages must start with a CDR encapsulation
// header (0x00 0x01: little-endian plain CDR, what ROS 2 writes).
"use strict";
const fs = require("node:fs/promises");
const { McapIndexedReader } = require("@mcap/core");
const fzstd = require("fzstd");

function parseSchema(schema) {
  const text = new TextDecoder().decode(schema.data);
  return schema.encoding === "jsonschema" ? JSON.parse(text) : text.split("\n")[0];
}

async function main() {
  const handle = await fs.open(process.argv[2], "r");
  const readable = {
    size: async () => BigInt((await handle.stat()).size),
    read: async (offset, length) => {
      const buffer = new Uint8Array(Number(length));
      await handle.read(buffer, 0, Number(length), Number(offset));
      return buffer;
    },
  };
  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: { zstd: (data, size) => fzstd.decompress(data, new Uint8Array(Number(size))) },
  });
  const channels = {};
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    channels[id] = { topic: channel.topic, encoding: channel.messageEncoding, count: 0, monotonic: true, last: -1n,
                     schema: schema && { name: schema.name, encoding: schema.encoding,
                                         parsed: parseSchema(schema) } };
  }
  for await (const message of reader.readMessages()) {
    const c = channels[message.channelId];
    c.count += 1;
    if (message.logTime < c.last) c.monotonic = false;
    c.last = message.logTime;
    if (c.encoding === "json") JSON.parse(new TextDecoder().decode(message.data)); // every payload is JSON
    else if (c.encoding === "cdr" && !(message.data[0] === 0 && message.data[1] === 1)) {
      throw new Error(`${c.topic}: not little-endian CDR (starts ${message.data[0]} ${message.data[1]})`);
    }
  }
  for (const c of Object.values(channels)) delete c.last;
  console.log(JSON.stringify({ library: reader.header.library, profile: reader.header.profile,
                               channels: Object.values(channels) }));
  await handle.close();
}

main().catch((err) => { console.error(err); process.exit(1); });
