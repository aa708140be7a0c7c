// The GI-map payload (baseline_cloudbaking.protocol): b"GIM1" | u32 header length | JSON header | sections.
// The image sections are 8-bit images the browser decodes; depth is zstd-f16-delta (baseline_cloudbaking.codecs:
// a u32 x 3 shape header, zstandard, two byte planes, each row's float16 bit patterns delta-coded). Imported by
// map_worker.js, where the cloud pane's maps are decoded.

import { decompress } from "/npm/fzstd/index.mjs";

const MEDIA = { jpeg: "image/jpeg", webp: "image/webp", png: "image/png", avif: "image/avif" };

export function unpack(buffer) {
  const bytes = new Uint8Array(buffer);
  const magic = String.fromCharCode(...bytes.subarray(0, 4));
  if (magic !== "GIM1") throw new Error(`not a GI-map payload (starts with ${JSON.stringify(magic)})`);
  const n = new DataView(buffer).getUint32(4, true);
  const header = JSON.parse(new TextDecoder().decode(bytes.subarray(8, 8 + n)));
  const sections = {};
  let offset = 8 + n;
  for (const s of header.sections) {
    sections[s.name] = bytes.subarray(offset, offset + s.bytes);
    offset += s.bytes;
  }
  if (offset !== bytes.length) throw new Error(`${bytes.length - offset} bytes follow the last section`);
  return { header, sections };
}

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

// Depth (HxW float32, rows top-down) from its zstd-f16-delta bytes.
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
