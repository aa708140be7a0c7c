// The cloud pane's maps, fetched and decoded in a module worker, off the page's thread: while the page draws
// back-to-back frames, its thread runs a response's tasks only between them, so bytes read there would wait for
// frames to be handed on. Given {id, url, body}, it POSTs the body, unpacks the GI-map payload, decodes the
// image to an ImageBitmap and the depth to a Float32Array and transfers both back: {id, header, bitmap, depth,
// h, w, bytes, times, scope, location (the stored map's /v1/maps/{sha})}, or {id, error} (one line). `times` (ms since the epoch, for the page to put on its
// own clock): started, firstByte, arrived (the network stack's, from Resource Timing where it has the entry;
// `timing` says which), and from, to: this decoding's start and end. `scope`: the global scope it ran in.

import { decodeDepth, decodeImage, unpack } from "./payload.js";

/** @typedef {import("./payload.js").MapReply} MapReply */

/**
 * @param {string} url
 * @param {string} body
 */
async function fetchMap(url, body) {
  const started = performance.now();
  const response = await fetch(url, { method: "POST", headers: { "Content-Type": "application/json" }, body });
  const firstByte = performance.now();
  if (!response.ok) throw new Error(`/v1/gimap answered ${response.status}: ${await response.text()}`);
  const buffer = await response.arrayBuffer();
  const arrived = performance.now();
  const entries = /** @type {PerformanceResourceTiming[]} */ (performance.getEntriesByType("resource"));
  const entry = entries.find((e) => e.name === url && e.startTime >= started - 1 && e.responseEnd > 0);
  performance.clearResourceTimings();
  const times = entry ? { started: entry.startTime, firstByte: entry.responseStart, arrived: entry.responseEnd }
    : { started, firstByte, arrived };
  return { buffer, times, timing: entry ? "resource" : "script", location: response.headers.get("Content-Location") };
}

/** @param {ArrayBuffer} buffer */
async function decode(buffer) {
  const { header, sections } = unpack(buffer);
  const bitmap = await decodeImage(header.codec, sections.gi);
  return { header, bitmap, ...decodeDepth(sections.depth) };
}

/** @param {MessageEvent<{id: number, url: string, body: string}>} event */
self.onmessage = async ({ data: { id, url, body } }) => {
  try {
    const { buffer, times, timing, location } = await fetchMap(url, body);
    const from = performance.now();
    const map = await decode(buffer);
    /** @param {number} t */
    const epoch = (t) => performance.timeOrigin + t;
    const all = { ...times, from, to: performance.now() };
    const onEpoch = Object.fromEntries(Object.entries(all).map(([k, t]) => [k, epoch(t)]));
    /** @type {MapReply} */
    const reply = { id, ...map, bytes: buffer.byteLength, timing, location, scope: self.constructor.name,
      times: /** @type {MapReply["times"]} */ (onEpoch) };
    self.postMessage(reply, [map.bitmap, map.depth.buffer]);
  } catch (e) {
    self.postMessage({ id, error: String(e instanceof Error ? e.message : e) });
  }
};
