// Reads one MCAP log with Foxglove's own TypeScript reader (@mcap/core, as Lichtblick bundles
// it): indexed (the summary's chunk and message indexes) and streamed (every record, every CRC
// checked), lz4 by Lichtblick's wasm-lz4; prints the messages per topic of each reading, the
// schemas and the summary's counts as one JSON line; exits 1 if the two readings differ.
// usage: node read.js LOG.mcap   (LICHTBLICK_SRC: the Lichtblick checkout with node_modules)
const src = process.env.LICHTBLICK_SRC || "/work/licht-build/lichtblick";
const fs = require("fs");
const need = (name) => require(require.resolve(name, { paths: [src] }));
const { McapIndexedReader, McapStreamReader } = need("@mcap/core");
const wasmLz4 = need("@lichtblick/wasm-lz4");
(async () => {
  const lz4 = wasmLz4.default || wasmLz4;
  await lz4.isLoaded;
  const decompressHandlers = { lz4: (buf, size) => new Uint8Array(lz4(buf, Number(size))) };
  const data = fs.readFileSync(process.argv[2]);
  const readable = {
    size: async () => BigInt(data.length),
    read: async (off, len) => new Uint8Array(data.buffer, data.byteOffset + Number(off), Number(len)),
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const indexed = {};
  for await (const m of reader.readMessages()) {
    const topic = reader.channelsById.get(m.channelId).topic;
    indexed[topic] = (indexed[topic] || 0) + 1;
  }
  const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  stream.append(new Uint8Array(data));
  const streamed = {};
  const topics = {};
  for (let rec; (rec = stream.nextRecord()); ) {
    if (rec.type === "Channel") topics[rec.id] = rec.topic;
    if (rec.type === "Message") streamed[topics[rec.channelId]] = (streamed[topics[rec.channelId]] || 0) + 1;
  }
  const sorted = (o) => JSON.stringify(Object.keys(o).sort().map((k) => [k, o[k]]));
  const same = sorted(indexed) === sorted(streamed);
  console.log(JSON.stringify({
    same, indexed, schemas: [...reader.schemasById.values()].map((s) => s.name).sort(),
    chunks: reader.chunkIndexes.length, attachments: reader.attachmentIndexes.length,
    metadata: reader.metadataIndexes.length,
  }));
  process.exit(same ? 0 : 1);
})().catch((e) => { console.error("cannot read:", e.message); process.exit(1); });
