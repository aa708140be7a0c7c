// One system's pane: its canvas's frame (DI, the bound GI map warped to the current view, eq. 1's blend) and its
// GI maps in flight. At most one request is in flight; a new one goes out when none is, the view or light differs
// from the last request's and, while the view moves, `every` frames have passed since it. The answer joins the
// frames in the first frame after it lands; nothing in a frame waits for one.

import { History } from "./history.js";

// `di`: the local render of the frame that first shows the map, counted for both systems as Table 1 counts it
// (docs/architecture.md, Honest accounting).
export const GIGAN_STAGES = ["gi_render", "inference", "di", "warp", "blend"];
export const CLOUD_STAGES = ["transmission", "server", "decode", "di", "warp", "blend"];
/** The maps a pane keeps for the HUD's medians (the page's own log of every map is the frame loop's). */
export const RECENT_MAPS = 100;

/** @typedef {import("./scene.js").Frame} Frame */
/** @typedef {import("./scene.js").SceneRenderer} SceneRenderer */
/** @typedef {import("./glutil.js").Target} Target */
/**
 * What a pane draws with: its system's warp and blend of the bound map (GiganSystem or CloudSystem).
 * @typedef {object} System
 * @property {unknown} bound the map bound, or null before the first
 * @property {(frame: Frame, di: Target) => void} warp
 * @property {(di: Target, tau: number) => void} blend
 * @property {import("./blend.js").Blend} blender
 */
/**
 * A request's synchronous half, from `start`: its answer's promise and what `join` needs of it.
 * @typedef {{run: Promise<any>} & Record<string, any>} Started
 */
/**
 * A GI map's record (viewer.maps): the system, the frame that requested it, its stages and their total (ms), and
 * what the system's join keeps (cloud: hit, bytes, profile, store, decoding).
 * @typedef {{system: string, frame: number, stages: Record<string, number>, total: number}
 *   & Record<string, any>} MapRecord
 */
/**
 * A pane's share of a drawn frame (see Pane.frame).
 * @typedef {{ms: number, land_ms: number, request_ms: number, sent: boolean, landed: boolean,
 *   map_frame: number | null, map_age_frames: number | null, map_age_ms: number | null, inflight: boolean,
 *   error: string | null}} PaneStats
 */
/**
 * @template {Started} S
 * @typedef {{index: number, key: string, captured: number, started: S, result: any, error: any}} InFlight
 */

/** @param {() => void} fn */
const elapsed = (fn) => {
  const t0 = performance.now();
  fn();
  return performance.now() - t0;
};

/**
 * Wait until the GPU has drawn the DI (one texel read back).
 * @param {import("./glutil.js").GL} gl
 * @param {Target} t
 */
function syncDI(gl, t) {
  const px = new Float32Array(4);
  gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
  gl.readBuffer(gl.COLOR_ATTACHMENT0);
  gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, px);
}

/** @template {Started} [S=Started] what a request's synchronous half returns */
export class Pane {
  /**
   * @param {object} options
   * @param {string} options.label the maps' system name
   * @param {System} options.system
   * @param {SceneRenderer} options.scene its canvas's renderer
   * @param {string[]} options.stages the stages a map's total sums
   * @param {number} options.every while the view moves, frames between requests
   * @param {(frame: Frame) => S} options.start a request's synchronous half
   * @param {(started: S, result: any) => {stages: Record<string, number>} & Record<string, any>} options.join
   *   its second half in the frame loop: the stages and what the map record keeps
   * @param {boolean} options.fatal a failed request stops the page (else the HUD shows it)
   */
  constructor({ label, system, scene, stages, every, start, join, fatal }) {
    this.label = label;
    this.system = system;
    this.scene = scene;
    this.stages = stages;
    this.every = every;
    this.start = start;
    this.join = join;
    this.fatal = fatal;
    /** @type {InFlight<S> | null} */
    this.inflight = null;
    /** @type {{index: number, key: string} | null} the last request's */
    this.last = null;
    /** @type {{index: number, captured: number} | null} the bound map's request */
    this.shown = null;
    /** @type {string | null} */
    this.error = null;
    /** @type {History<MapRecord>} this pane's last maps, for the HUD; its count: every map it made */
    this.recent = new History(`${label} maps`, RECENT_MAPS);
  }

  /**
   * A new map is due at this frame (see the module comment).
   * @param {number} index
   * @param {string} key
   * @param {boolean} moving
   */
  wants(index, key, moving) {
    if (this.inflight) return false;
    if (!this.last) return true;
    return key !== this.last.key && (!moving || index - this.last.index >= this.every);
  }

  landed() {
    return Boolean(this.inflight && (this.inflight.result || this.inflight.error));
  }

  /**
   * Send a request for `frame` (frame `index`, its view and light `key`).
   * @param {number} index
   * @param {string} key
   * @param {Frame} frame
   */
  request(index, key, frame) {
    const started = this.start(frame);
    const f = (this.inflight = { index, key, captured: performance.now(), started, result: null, error: null });
    this.last = { index, key };
    started.run.then((r) => (f.result = r), (e) => (f.error = e));
  }

  // A new map is wanted at once (another profile or store), whatever the last request's view.
  forget() {
    this.last = null;
  }

  /**
   * The landed answer bound; its map record, to be completed by this frame's warp and blend.
   * @returns {MapRecord | null}
   */
  land() {
    const f = /** @type {InFlight<S>} */ (this.inflight);
    this.inflight = null;
    if (f.error) {
      if (this.fatal) throw f.error;
      this.error = String(f.error.message || f.error);
      return null;
    }
    this.error = null;
    const { stages, ...extra } = this.join(f.started, f.result);
    this.shown = { index: f.index, captured: f.captured };
    return { system: this.label, frame: f.index, stages, total: NaN, ...extra };
  }

  // One frame: land an answer, send a request when one is due (not while `hold`), draw. Returns the frame's
  // statistics for this pane (`stats`: its time, ms: landing, sending and drawing, land_ms and request_ms the first
  // two; whether it sent a request and whether an answer landed, the map shown and its age, a request in flight
  // after it), the DI's time (`di`, ms) and the map that landed, completed (`map`, or null).
  /**
   * @param {number} index
   * @param {string} key
   * @param {boolean} moving
   * @param {Frame} frame
   * @param {number} tau
   * @param {boolean} hold
   * @returns {{stats: PaneStats, di: number, map: MapRecord | null}}
   */
  frame(index, key, moving, frame, tau, hold) {
    const start = performance.now();
    const landed = this.landed();
    /** @type {MapRecord | null} */
    let map = null;
    const landMs = landed ? elapsed(() => (map = this.land())) : 0;
    const sent = !hold && this.wants(index, key, moving);
    const requestMs = sent ? elapsed(() => this.request(index, key, frame)) : 0;
    const di = this.scene.diTarget;
    const diMs = elapsed(() => syncDI(this.scene.gl, this.scene.renderDI(frame)));
    const sys = this.system;
    if (sys.bound) {
      const warp = elapsed(() => sys.warp(frame, di));
      const blend = elapsed(() => sys.blend(di, tau));
      if (map) this.record(map, diMs, warp, blend);
    } else {
      sys.blender.draw(di.textures[0], di.textures[0], tau); // no map yet: the DI alone
    }
    const now = performance.now();
    const shown = this.shown;
    const stats = {
      ms: now - start, land_ms: landMs, request_ms: requestMs, sent, landed,
      map_frame: shown ? shown.index : null, map_age_frames: shown ? index - shown.index : null,
      map_age_ms: shown ? now - shown.captured : null, inflight: Boolean(this.inflight), error: this.error,
    };
    return { stats, di: diMs, map };
  }

  /**
   * @param {MapRecord} map
   * @param {number} di
   * @param {number} warp
   * @param {number} blend
   */
  record(map, di, warp, blend) {
    const s = map.stages;
    s.di = di;
    s.warp = s.bind + warp;
    s.blend = blend;
    map.total = this.stages.reduce((a, k) => a + s[k], 0);
    this.recent.push(map);
  }
}
