// The page's settings: gigan-web's /config.json, each key overridden by the URL's parameter of that name; also
// ?autoplay=1&frames=N (replay the scripted path's first N frames, let the maps in flight land, then viewer.done)
// and ?record=1 (record from the first frame).

/**
 * @typedef {object} Config
 * @property {string} scene
 * @property {number} frames the scripted path's frames an autoplay replays
 * @property {number} every while the view moves, frames between a pane's requests
 * @property {number} tau eq. 1's weight of the DI
 * @property {string} codec the cloud maps' image codec
 * @property {number} spp the cloud maps' samples per pixel
 * @property {string} backend onnxruntime-web's: auto, wasm or webgpu
 * @property {number} threads onnxruntime-web's wasm threads
 * @property {number} resolution the maps' and canvases' pixels (square)
 * @property {number} record_frames_max the most frames a recording holds (a path file's)
 * @property {string[]} profiles the cloud side's network profiles (none: the cloud is off)
 * @property {string | null} profile the default
 * @property {string[]} stores the cloud side's stores
 * @property {string | null} store the default
 * @property {boolean} autoplay
 * @property {boolean} record
 */

const NUMBERS = ["frames", "every", "tau", "spp", "threads", "resolution", "record_frames_max"];

/**
 * A JSON document of the page's origin.
 * @param {string} url
 */
export async function json(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: ${r.status}`);
  return r.json();
}

/**
 * /config.json with the URL's parameters `params` over it.
 * @param {URLSearchParams} params
 * @returns {Promise<Config>}
 */
export async function loadConfig(params) {
  const config = { ...(await json("/config.json")), ...Object.fromEntries(params) };
  for (const k of NUMBERS) config[k] = Number(config[k]);
  config.autoplay = config.autoplay === "1";
  config.record = config.record === "1";
  return config;
}
