// The GI-map payload (baseline_cloudbaking.protocol): b"GIM1" | u32 header length | JSON header | sections.
// The image sections are 8-bit images the browser decodes; depth is zstd-f16-delta (baseline_cloudbaking.codecs:
// a u32 x 3 shape header, zstandard, two byte planes, each row's float16 bit patterns delta-coded). Imported by
// map_worker.js, where the cloud pane's maps are decoded.

import { decompress } from "/npm/fzstd/index.mjs";

/**
 * The payload's JSON header as the page reads it: its sections, the GI camera's view and projection (rows), the
 * store's answer and the server's stage timings.
 * @typedef {{codec: string, sections: {name: string, bytes: number}[], view: number[][], proj: number[][],
 *   hit: boolean, timings_ms?: Record<string, number>}} Header
 */
/**
 * map_worker.js's reply for one map: the decoded image and depth, the payload's size, where the stored map lives
 * (/v1/maps/{sha}), its times (ms since the epoch) and where and how they were taken; or {id, error}.
 * @typedef {{id: number, header: Header, bitmap: ImageBitmap, depth: Float32Array, h: number, w: number,
 *   bytes: number, timing: string, location: string | null, scope: string,
 *   times: Record<"started" | "firstByte" | "arrived" | "from" | "to", number>}} MapReply
 */

/** @type {Record<string, string>} */
const MEDIA = { jpeg: "image/jpeg", webp: "image/webp", png: "image/png", avif: "image/avif" };

/**
 * @param {ArrayBuffer} buffer
 * @returns {{header: Header, sections: Record<string, Uint8Array<ArrayBuffer>>}}
 */
export function unpack(buffer) {
  const bytes = new Uint8Array(buffer);
  const magic = String.fromCharCode(...bytes.subarray(0, 4));
  if (magic !== "GIM1") throw new Error(`not a GI-map payload (starts with ${JSON.stringify(magic)})`);
  const n = new DataView(buffer).getUint32(4, true);
  const header = JSON.parse(new TextDecoder().decode(bytes.subarray(8, 8 + n)));
  /** @type {Record<string, Uint8Array<ArrayBuffer>>} */
  const sections = {};
  let offset = 8 + n;
  for (const s of header.sections) {
    sections[s.name] = bytes.subarray(offset, offset + s.bytes);
    offset += s.bytes;
  }
  if (offset !== bytes.length) throw new Error(`${bytes.length - offset} bytes follow the last section`);
  return { header, sections };
}

/**
 * @param {string} codec
 * @param {Uint8Array<ArrayBuffer>} data
 */
export async function decodeImage(codec, data) {
  const media = MEDIA[codec];
  if (!media) throw new Error(`the page decodes 8-bit images only, not ${codec}`);
  // raw pixel values: no colour-space conversion or premultiplication (they are tone-mapped radiance)
  return createImageBitmap(new Blob([data], { type: media }), {
    colorSpaceConversion: "none", premultiplyAlpha: "none", imageOrientation: "from-image",
  });
}

const f16 = (() => {
  const table = new Float32Array(65536);
  for (let h = 0; h < 65536; h++) {
    const s = h & 0x8000 ? -1 : 1;
    const e = (h >> 10) & 0x1f;
    const m = h & 0x3ff;
    table[h] = e === 0 ? s * m * 2 ** -24 : e === 31 ? (m ? NaN : s * Infinity) : s * (1 + m / 1024) * 2 ** (e - 15);
  }
  return table;
})();

/**
 * Depth (HxW float32, rows top-down) from its zstd-f16-delta bytes.
 * @param {Uint8Array} data
 */
export function decodeDepth(data) {
  const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
  const h = view.getUint32(0, true);
  const w = view.getUint32(4, true);
  const raw = decompress(data.subarray(12));
  const count = h * w;
  if (raw.length !== 2 * count) throw new Error(`depth: ${raw.length} bytes for a ${h}x${w} map`);
  const out = new Float32Array(count);
  for (let r = 0; r < h; r++) {
    let bits = 0;
    for (let c = 0; c < w; c++) {
      const i = r * w + c;
      bits = (bits + (raw[i] | (raw[count + i] << 8))) & 0xffff; // low byte plane, then high byte plane
      out[i] = f16[bits];
    }
  }
  return { depth: out, h, w };
}
