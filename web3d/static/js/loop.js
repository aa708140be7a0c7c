// The frame loop: requestAnimationFrame drives both panes. A tick takes the camera from the controls (a replay
// moves them first), the light (the newest requested one whose shadow setup has arrived), then each pane lands an
// answer, sends a request when one is due and draws. A tick with nothing new (the same view and light, no answer
// landed, no request due, no replay) draws nothing. No tick waits for an inference or the network.

import { forGL } from "./camera.js";

export class FrameLoop {
  // `camera`: scene.json's camera (fovs, near, far, up); `start`: the first {light, setup}; `onFrame(record,
  // frame)`: after each drawn frame (recording, HUD); `fail(error)`: stops the page.
  constructor({ viewer, navigation, light, shadows, camera, tau, onFrame, fail, start }) {
    Object.assign(this, { viewer, navigation, light, shadows, camera, tau, onFrame, fail });
    this.panes = []; // [gigan, cloud or null], set once they exist
    this.applied = start; // {light, setup}: the light frames draw
    this.prevKey = null;
    this.driver = null; // a Replay
    this.hold = false; // no new requests (an autoplay's drain, and after it until a person's input)
    this.drained = [];
    this.tick = this.tick.bind(this);
  }

  start() {
    requestAnimationFrame(this.tick);
  }

  tick(now) {
    if (this.viewer.error) return; // stopped (a failed shadow fetch, say)
    try {
      this.step(now);
    } catch (e) {
      this.fail(e);
      return;
    }
    requestAnimationFrame(this.tick);
  }

  // The frame's local and GI cameras (WebGL's Float32Array matrices) at `pose`, and the light.
  frameAt(pose) {
    const c = this.camera;
    const cam = { eye: pose.eye, target: pose.target, up: c.up, near: c.near, far: c.far };
    const { light, setup } = this.applied;
    return { local: forGL({ ...cam, fov: c.local_fov }), gi: forGL({ ...cam, fov: c.gi_fov }), light, shadow: setup };
  }

  // What a map depends on: the view and the light drawn.
  key(pose) {
    return JSON.stringify([pose.eye, pose.target, this.applied.light]);
  }

  step(now) {
    const index = this.viewer.frames.length;
    let replayed = this.driver ? this.driver.step(now) : null;
    if (replayed === -1) this.driver = replayed = null;
    const pose = this.navigation.pose();
    const requested = this.light.value;
    const setup = this.shadows.get(requested, this.fail);
    if (setup) this.applied = { light: requested, setup };
    const key = this.key(pose);
    const moving = key !== this.prevKey;
    const panes = this.panes.filter(Boolean);
    const due = (p) => p.landed() || (!this.hold && p.wants(index, key, false));
    if (replayed === null && !moving && !panes.some(due)) {
      this.checkDrained();
      return;
    }
    this.prevKey = key;
    const t0 = performance.now();
    const frame = this.frameAt(pose);
    const [g, c] = this.panes.map((p) => p && p.frame(index, key, moving, frame, this.tau, this.hold));
    const strip = ({ di, ...rest }) => rest;
    const record = {
      t: now, frame_ms: performance.now() - t0, gigan_di: g.di, ...(c ? { cloud_di: c.di } : {}),
      gigan: strip(g), cloud: c ? strip(c) : null, replay: replayed,
    };
    this.viewer.frames.push(record);
    this.onFrame(record, frame);
    this.checkDrained();
  }

  // Play a Replay (one of its frames per drawn frame); resolves when it is done.
  play(replay) {
    if (this.driver) throw new Error("replay: another replay is playing");
    this.driver = replay;
    return replay.done;
  }

  // Resolves once no request is in flight, sending no new ones meanwhile (and after, until release()).
  drain() {
    this.hold = true;
    return new Promise((resolve) => this.drained.push(resolve));
  }

  release() {
    this.hold = false;
  }

  checkDrained() {
    if (!this.drained.length || this.panes.some((p) => p && p.inflight)) return;
    this.drained.splice(0).forEach((resolve) => resolve());
  }
}
