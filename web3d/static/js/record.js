// Path files ("gigan-path/1", docs/architecture.md, Path files): recording what the page rendered, one entry per
// rendered frame, and replaying one, one path frame per rendered frame.

export const PATH_FORMAT = "gigan-path/1";

export class Recorder {
  constructor(scene) {
    this.scene = scene;
    this.frames = [];
    this.t0 = null;
    this.on = false;
  }

  // Start a new recording (its t_ms count from its first frame), or stop.
  set(on) {
    if (on && !this.on) {
      this.frames = [];
      this.t0 = null;
    }
    this.on = on;
  }

  // A rendered frame's camera (the local one) and light.
  push(now, camera, light) {
    if (!this.on) return;
    if (this.t0 === null) this.t0 = now;
    const { eye, target, up, fov, near, far } = camera;
    this.frames.push({ t_ms: now - this.t0, camera: { eye, target, up, fov, near, far }, light: [...light] });
  }

  doc() {
    return { format: PATH_FORMAT, scene: this.scene, source: "recorded in gigan-web", frames: this.frames };
  }
}

// The recording as session-<time>.json, downloaded.
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
  constructor(doc, realtime, apply) {
    if (doc?.format !== PATH_FORMAT || !Array.isArray(doc.frames) || !doc.frames.length) {
      throw new Error(`replay: not a ${PATH_FORMAT} path file with frames`);
    }
    Object.assign(this, { frames: doc.frames, realtime, apply, next: 0, t0: null });
    this.done = new Promise((resolve) => (this.resolve = resolve));
  }

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
