// One system's pane: its canvas's frame (DI, the bound GI map warped to the current view, eq. 1's blend) and its
// GI maps in flight. At most one request is in flight; a new one goes out when none is, the view or light differs
// from the last request's and, while the view moves, `every` frames have passed since it. The answer joins the
// frames in the first frame after it lands; nothing in a frame waits for one.

// `di`: the local render of the frame that first shows the map, counted for both systems as Table 1 counts it
// (docs/architecture.md, Honest accounting).
export const GIGAN_STAGES = ["gi_render", "inference", "di", "warp", "blend"];
export const CLOUD_STAGES = ["transmission", "server", "decode", "di", "warp", "blend"];

const elapsed = (fn) => {
  const t0 = performance.now();
  fn();
  return performance.now() - t0;
};

// Wait until the GPU has drawn the DI (one texel read back).
function syncDI(gl, t) {
  const px = new Float32Array(4);
  gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
  gl.readBuffer(gl.COLOR_ATTACHMENT0);
  gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, px);
}

export class Pane {
  // `system`: GiganSystem or CloudSystem (warp, blend, blender); `start(frame)`: a request's synchronous half,
  // returning {run: Promise, ...}; `join(started, result)`: its second half in the frame loop, returning
  // {stages, ...what the map record keeps}; `fatal`: a failed request stops the page (else the HUD shows it);
  // `label`: the maps' system name; `maps`: where finished map records go (viewer.maps).
  constructor({ label, system, scene, stages, every, start, join, fatal, maps }) {
    Object.assign(this, { label, system, scene, stages, every, start, join, fatal, maps });
    this.inflight = null; // {index, key, captured, started, result, error}
    this.last = null; // the last request's {index, key}
    this.shown = null; // the bound map's request {index, captured}
    this.error = null;
  }

  // A new map is due at this frame (see the module comment).
  wants(index, key, moving) {
    if (this.inflight) return false;
    if (!this.last) return true;
    return key !== this.last.key && (!moving || index - this.last.index >= this.every);
  }

  landed() {
    return Boolean(this.inflight && (this.inflight.result || this.inflight.error));
  }

  // Send a request for `frame` (frame `index`, its view and light `key`).
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

  // The landed answer bound; its map record, to be completed by this frame's warp and blend.
  land() {
    const f = this.inflight;
    this.inflight = null;
    if (f.error) {
      if (this.fatal) throw f.error;
      this.error = String(f.error.message || f.error);
      return null;
    }
    this.error = null;
    const { stages, ...extra } = this.join(f.started, f.result);
    this.shown = { index: f.index, captured: f.captured };
    return { system: this.label, frame: f.index, stages, ...extra };
  }

  // One frame: land an answer, send a request when one is due (not while `hold`), draw. Returns the frame's
  // statistics for this pane: its time (ms: landing, sending and drawing; land_ms and request_ms the first two),
  // whether it sent a request and whether an answer landed, the map shown and its age, a request in flight after it.
  frame(index, key, moving, frame, tau, hold) {
    const start = performance.now();
    const landed = this.landed();
    let map = null;
    const landMs = landed ? elapsed(() => (map = this.land())) : 0;
    const sent = !hold && this.wants(index, key, moving);
    const requestMs = sent ? elapsed(() => this.request(index, key, frame)) : 0;
    let di;
    const diMs = elapsed(() => {
      di = this.scene.renderDI(frame);
      syncDI(this.scene.gl, di);
    });
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
    return {
      ms: now - start, land_ms: landMs, request_ms: requestMs, sent, landed, di: diMs,
      map_frame: shown ? shown.index : null, map_age_frames: shown ? index - shown.index : null,
      map_age_ms: shown ? now - shown.captured : null, inflight: Boolean(this.inflight), error: this.error,
    };
  }

  record(map, di, warp, blend) {
    const s = map.stages;
    s.di = di;
    s.warp = s.bind + warp;
    s.blend = blend;
    map.total = this.stages.reduce((a, k) => a + s[k], 0);
    this.maps.push(map);
  }
}
