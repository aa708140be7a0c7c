// Path files ("gigan-path/1", docs/architecture.md, Path files): recording what the page rendered, one entry per
// rendered frame, and replaying one, one path frame per rendered frame. A recording holds at most as many frames
// as a path file the clients read may (/config.json's record_frames_max): once full it takes no more and says so.

/** @typedef {import("./camera.js").CameraSpec} CameraSpec */
/** @typedef {{t_ms: number, camera: CameraSpec, light: number[]}} PathFrame */
/** @typedef {{format: string, scene: string, source?: string, frames: PathFrame[]}} PathDoc */

export const PATH_FORMAT = "gigan-path/1";

export class Recorder {
  /**
   * @param {string} scene the scene's name, written into the path file
   * @param {number} limit the most frames one recording holds
   */
  constructor(scene, limit) {
    this.scene = scene;
    this.limit = limit;
    /** @type {PathFrame[]} */
    this.frames = [];
    /** @type {number | null} */
    this.t0 = null;
    this.on = false;
  }

  /**
   * Start a new recording (its t_ms count from its first frame), or stop.
   * @param {boolean} on
   */
  set(on) {
    if (on && !this.on) {
      this.frames = [];
      this.t0 = null;
    }
    this.on = on;
  }

  /** Whether the recording holds all the frames it may (the frames drawn since are not in it). */
  get full() {
    return this.frames.length >= this.limit;
  }

  /**
   * A rendered frame's camera (the local one) and light.
   * @param {number} now
   * @param {CameraSpec} camera
   * @param {number[]} light
   */
  push(now, camera, light) {
    if (!this.on || this.full) return;
    if (this.t0 === null) this.t0 = now;
    const { eye, target, up, fov, near, far } = camera;
    this.frames.push({ t_ms: now - this.t0, camera: { eye, target, up, fov, near, far }, light: [...light] });
  }

  /** @returns {PathDoc} */
  doc() {
    return { format: PATH_FORMAT, scene: this.scene, source: "recorded in gigan-web", frames: this.frames };
  }

  /** The HUD's words for it: empty when not recording. */
  describe() {
    if (!this.on) return "";
    const n = this.frames.length.toLocaleString("en");
    return this.full ? `● recording full at ${n} frames, the most a path file holds: Stop downloads it`
      : `● recording (${n} frames)`;
  }
}

/**
 * The recording as session-<time>.json, downloaded.
 * @param {PathDoc} doc
 */
export function download(doc) {
  const stamp = new Date().toISOString().replace(/[:.]/g, "-");
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([JSON.stringify(doc)], { type: "application/json" }));
  a.download = `session-${stamp}.json`;
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 0);
}

// A path file's frames played through `apply(frame)`: one per rendered frame, or (`realtime`) per rendered frame
// the latest whose t_ms has passed since the first (held while the next one's has not). step() gives the index
// applied this frame, or -1 once past the last; `done` resolves with the last frame drawn.
export class Replay {
  /**
   * @param {PathDoc} doc
   * @param {boolean} realtime
   * @param {(frame: PathFrame) => void} apply
   */
  constructor(doc, realtime, apply) {
    if (doc?.format !== PATH_FORMAT || !Array.isArray(doc.frames) || !doc.frames.length) {
      throw new Error(`replay: not a ${PATH_FORMAT} path file with frames`);
    }
    this.frames = doc.frames;
    this.realtime = realtime;
    this.apply = apply;
    this.next = 0;
    /** @type {number | null} */
    this.t0 = null;
    /** @type {() => void} */
    this.resolve = () => {};
    /** @type {Promise<void>} */
    this.done = new Promise((resolve) => (this.resolve = resolve));
  }

  /** @param {number} now */
  step(now) {
    const frames = this.frames;
    if (this.next >= frames.length) return -1;
    let i = this.next;
    if (this.realtime) { // hold the last frame applied until the next one's time has come
      if (this.t0 === null) this.t0 = now - frames[0].t_ms;
      i = Math.max(i - 1, 0);
      while (i + 1 < frames.length && frames[i + 1].t_ms <= now - this.t0) i++;
    }
    this.apply(frames[i]);
    this.next = i + 1;
    if (this.next === frames.length) this.resolve(); // its awaiters run once this frame is drawn
    return i;
  }
}
