// Checks gyrolab's viewer topics with independent code: @mcap/core reads the file, the
// foxglove.Log messages are validated (ajv) against the schema @foxglove/schemas ships for
// the Log panel, /gyro/rate_summary against the JSON Schema stored in the file, and every
// summary is recomputed from the /gyro/rate block it summarises (protobuf decoded here).
// Prints one JSON object for tests/test_viewer_topics.py.
//
// usage: node check_viewer_topics.mjs FILE.mcap  (node_modules beside it: @mcap/core, fzstd,
//        @foxglove/schemas, ajv)
import { readFile } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { decompress as zstdDecompress } from "fzstd";
import foxgloveSchemas from "@foxglove/schemas/jsonschema.js";
import Ajv from "ajv";

const decompressHandlers = {
  zstd: (buffer, size) => zstdDecompress(buffer, new Uint8Array(Number(size))),
};
const bytes = new Uint8Array(await readFile(process.argv[2]));
const readable = {
  size: async () => BigInt(bytes.byteLength),
  read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
};
const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
const ajv = new Ajv({ strict: false });
const foxLog = { ...foxgloveSchemas.Log };
const validateLog = ajv.compile(foxLog);
let validateSummary = null;
let storedLogSchema = null;

function varint(buf, i) {
  let v = 0n, shift = 0n, b;
  do { b = buf[i++]; v |= BigInt(b & 0x7f) << shift; shift += 7n; } while (b & 0x80);
  return [v, i];
}
function decodeRate(buf) {
  // gyrolab.GyroRateBlock: 1 t0 double, 2 period double, 3 first_index varint, 4 packed float
  const dv = new DataView(buf.buffer, buf.byteOffset, buf.byteLength);
  let i = 0; const out = { t0: 0, period: 0, first: 0n, rate: new Float32Array(0) };
  while (i < buf.length) {
    let key; [key, i] = varint(buf, i);
    const f = Number(key >> 3n), wt = Number(key & 7n);
    if (wt === 1) { const v = dv.getFloat64(i, true); i += 8; if (f === 1) out.t0 = v; else if (f === 2) out.period = v; }
    else if (wt === 0) { let v; [v, i] = varint(buf, i); if (f === 3) out.first = v; }
    else if (wt === 2) {
      let len; [len, i] = varint(buf, i); len = Number(len);
      if (f === 4) { const a = new Float32Array(len / 4); for (let k = 0; k < a.length; k++) a[k] = dv.getFloat32(i + 4 * k, true); out.rate = a; }
      i += len;
    } else throw new Error(`wire type ${wt}`);
  }
  return out;
}

const res = { logs: 0, log_errors: [], levels: {}, summaries: 0, summary_errors: [],
  max_mean_diff: 0, max_minmax_diff: 0, n_mismatch: 0, stamp_max_err_ns: 0, rate_blocks: 0,
  schema_names: {}, log_schema_equal: null, first_log: null };
const blocks = new Map();
const summaries = [];
for await (const msg of reader.readMessages({ validateCrcs: true })) {
  const ch = reader.channelsById.get(msg.channelId);
  const schema = reader.schemasById.get(ch.schemaId);
  res.schema_names[ch.topic] = schema?.name ?? "";
  if (ch.topic === "/gyro/rate") { const b = decodeRate(msg.data); blocks.set(b.first, b); res.rate_blocks++; }
  if (ch.topic === "/log/foxglove") {
    if (storedLogSchema === null) storedLogSchema = JSON.parse(new TextDecoder().decode(schema.data));
    const m = JSON.parse(new TextDecoder().decode(msg.data));
    res.logs++;
    if (res.first_log === null) res.first_log = m;
    if (!validateLog(m)) res.log_errors.push(ajv.errorsText(validateLog.errors));
    res.levels[m.level] = (res.levels[m.level] ?? 0) + 1;
    const ns = BigInt(m.timestamp.sec) * 1000000000n + BigInt(m.timestamp.nsec);
    res.stamp_max_err_ns = Math.max(res.stamp_max_err_ns, Math.abs(Number(ns - msg.logTime)));
  }
  if (ch.topic === "/gyro/rate_summary") {
    if (validateSummary === null) validateSummary = ajv.compile(JSON.parse(new TextDecoder().decode(schema.data)));
    const m = JSON.parse(new TextDecoder().decode(msg.data));
    if (!validateSummary(m)) res.summary_errors.push(ajv.errorsText(validateSummary.errors));
    summaries.push([m, msg.logTime]);
  }
}
for (const [m] of summaries) {
  res.summaries++;
  const b = blocks.get(BigInt(m.first_index));
  if (!b || b.rate.length !== m.n) { res.n_mismatch++; continue; }
  let s = 0, lo = Infinity, hi = -Infinity;
  for (const v of b.rate) { s += v; lo = Math.min(lo, v); hi = Math.max(hi, v); }
  res.max_mean_diff = Math.max(res.max_mean_diff, Math.abs(s / b.rate.length - m.mean_dps));
  res.max_minmax_diff = Math.max(res.max_minmax_diff, Math.abs(lo - m.min_dps), Math.abs(hi - m.max_dps));
}
const { $comment, ...ref } = foxgloveSchemas.Log;
res.log_schema_equal = JSON.stringify(sortKeys(storedLogSchema)) === JSON.stringify(sortKeys(ref));
function sortKeys(x) {
  if (Array.isArray(x)) return x.map(sortKeys);
  if (x && typeof x === "object") return Object.fromEntries(Object.keys(x).sort().map((k) => [k, sortKeys(x[k])]));
  return x;
}
console.log(JSON.stringify(res));
