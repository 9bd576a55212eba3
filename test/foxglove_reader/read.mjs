// Reads an MCAP bag the way the Foxglove app does (test/test_bag_readers.py, docs/bags.md):
// @mcap/core's indexed reader (zstd/lz4 chunks through Foxglove's wasm decompressors), each
// ros2msg schema through @foxglove/rosmsg's parse(text, {ros2: true}), each message through
// @foxglove/rosmsg2-serialization's MessageReader.
//
// usage: node read.mjs FILE.mcap
// stdout: one JSON object {schemas: {name: "ok" | error}, topics: {topic: {type, count,
//   decoded, stamps}}, errors: [...]}, stamps being the decoded header.stamp (or clock) of each
//   message that has one, in ns as decimal strings; exit 0 when every schema parsed and every
//   message decoded.
import { open } from "node:fs/promises";

import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import lz4 from "@foxglove/wasm-lz4";
import * as zstd from "@foxglove/wasm-zstd";
import { McapIndexedReader } from "@mcap/core";

const path = process.argv[2];
if (!path) {
  console.error("usage: node read.mjs FILE.mcap");
  process.exit(2);
}
await zstd.isLoaded;
await lz4.isLoaded;

const handle = await open(path, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, size) => {
    const buf = new Uint8Array(Number(size));
    const { bytesRead } = await handle.read(buf, 0, Number(size), Number(offset));
    if (bytesRead !== Number(size)) {
      throw new Error(`short read at ${offset}: ${bytesRead} of ${size} bytes`);
    }
    return buf;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: {
    zstd: (buffer, size) => zstd.decompress(buffer, Number(size)),
    lz4: (buffer, size) => lz4(buffer, Number(size)),
  },
});

const out = { profile: reader.header.profile, schemas: {}, topics: {}, errors: [] };
const readers = new Map();                       // schema id -> MessageReader | null
const text = new TextDecoder();
for (const [id, schema] of reader.schemasById) {
  if (schema.encoding !== "ros2msg") {
    out.schemas[schema.name] = `encoding ${schema.encoding}, not ros2msg`;
    readers.set(id, null);
    continue;
  }
  try {
    readers.set(id, new MessageReader(parse(text.decode(schema.data), { ros2: true })));
    out.schemas[schema.name] = "ok";
  } catch (err) {
    out.schemas[schema.name] = String(err.message ?? err);
    readers.set(id, null);
  }
}
for (const channel of reader.channelsById.values()) {
  const schema = reader.schemasById.get(channel.schemaId);
  out.topics[channel.topic] = { type: schema?.name ?? "", count: 0, decoded: 0, stamps: [] };
}
for await (const message of reader.readMessages({ validateCrcs: true })) {
  const channel = reader.channelsById.get(message.channelId);
  const entry = out.topics[channel.topic];
  entry.count += 1;
  const decoder = readers.get(channel.schemaId);
  if (!decoder) {
    continue;
  }
  try {
    const value = decoder.readMessage(message.data);
    if (value === undefined || value === null) {
      throw new Error("decoded to nothing");
    }
    entry.decoded += 1;
    const stamp = value.header?.stamp ?? value.clock;
    if (stamp !== undefined) {
      entry.stamps.push(String(BigInt(stamp.sec) * 1000000000n + BigInt(stamp.nanosec)));
    }
  } catch (err) {
    if (out.errors.length < 20) {
      out.errors.push(`${channel.topic} #${message.sequence}: ${err.message ?? err}`);
    }
  }
}
await handle.close();
console.log(JSON.stringify(out));
const bad = Object.values(out.schemas).some((s) => s !== "ok") ||
  Object.values(out.topics).some((t) => t.decoded !== t.count) || out.errors.length > 0;
process.exit(bad ? 1 : 0);
