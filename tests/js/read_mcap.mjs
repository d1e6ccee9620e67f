// Reads a gyrolab recording with the TypeScript MCAP implementation (@mcap/core), twice:
// the indexed reader (summary, chunk and message indexes, CRCs) and the stream reader
// (every record in file order). Prints one JSON object; tests/test_mcap_interop.py
// compares it with what gyrolab's Python reader sees.
//
// usage: node read_mcap.mjs FILE.mcap   (NODE_PATH or a node_modules beside it holds
//        @mcap/core and fzstd)
import { readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { decompress as zstdDecompress } from "fzstd";

const decompressHandlers = {
  zstd: (buffer, decompressedSize) => zstdDecompress(buffer, new Uint8Array(Number(decompressedSize))),
};

const path = process.argv[2];
const bytes = new Uint8Array(await readFile(path));
const readable = {
  size: async () => BigInt(bytes.byteLength),
  read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
};

const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
const indexed = {};
const encodings = {};
let first = null;
for await (const msg of reader.readMessages({ validateCrcs: true })) {
  const ch = reader.channelsById.get(msg.channelId);
  indexed[ch.topic] = (indexed[ch.topic] ?? 0) + 1;
  const schema = reader.schemasById.get(ch.schemaId);
  encodings[ch.topic] = [ch.messageEncoding, schema?.encoding ?? "", schema?.name ?? ""];
  if (first === null && ch.messageEncoding === "json") {
    first = { topic: ch.topic, message: JSON.parse(new TextDecoder().decode(msg.data)) };
  }
}
const metadata = {};
for await (const m of reader.readMetadata()) {
  metadata[m.name] = Object.fromEntries(m.metadata);
}
const stats = reader.statistics;

const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(bytes);
const streamed = {};
const channels = new Map();
let rec;
while ((rec = stream.nextRecord())) {
  if (rec.type === "Channel") channels.set(rec.id, rec.topic);
  if (rec.type === "Message") {
    const topic = channels.get(rec.channelId);
    streamed[topic] = (streamed[topic] ?? 0) + 1;
  }
}

console.log(
  JSON.stringify({
    profile: reader.header.profile,
    library: reader.header.library,
    indexed,
    streamed,
    stream_done: stream.done(),
    statistics_message_count: stats ? Number(stats.messageCount) : null,
    chunk_count: reader.chunkIndexes.length,
    encodings,
    metadata,
    first_json: first,
  }),
);
