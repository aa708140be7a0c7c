// The frame loop: requestAnimationFrame drives both panes. A tick takes the camera from the controls (a replay
// moves them first), the light (the newest requested one whose shadow setup has arrived), then each pane lands an
// answer, sends a request when one is due and draws. A tick with nothing new (the same view and light, no answer
// landed, no request due, no replay) draws nothing. No tick waits for an inference or the network. The loop keeps
// the records of the last frames drawn and maps made (viewer.frames, viewer.maps), for the HUD and the page's drivers.

import { forGL } from "./camera.js";
import { History } from "./history.js";

/** Frames and GI maps the page keeps (viewer.frames, viewer.maps): a driver reads them at least this often. */
export const FRAMES_KEPT = 4096;
export const MAPS_KEPT = 1024;

/** @typedef {import("./pane.js").Pane<any>} Pane */
/** @typedef {import("./pane.js").PaneStats} PaneStats */
/** @typedef {import("./pane.js").MapRecord} MapRecord */
/** @typedef {import("./scene.js").Frame} Frame */
/** @typedef {import("./camera.js").CameraSpec} CameraSpec */
/** @typedef {import("./light.js").ShadowSetup} ShadowSetup */
/**
 * A drawn frame's record (viewer.frames): when (the animation frame's time, ms) and how long it took, each pane's
 * DI time and statistics (cloud: null when off), the path frame a replay applied (or null), its local camera and
 * its light.
 * @typedef {{t: number, frame_ms: number, gigan_di: number, cloud_di?: number, gigan: PaneStats,
 *   cloud: PaneStats | null, replay: number | null, camera: CameraSpec, light: number[]}} FrameRecord
 */

export class FrameLoop {
  /**
   * @param {object} options
   * @param {import("./controls.js").Navigation} options.navigation
   * @param {import("./light.js").LightInput} options.light the requested light
   * @param {import("./light.js").ShadowSetups} options.shadows
   * @param {import("./scene.js").SceneCamera} options.camera scene.json's camera (fovs, near, far, up)
   * @param {number} options.tau eq. 1's weight of the DI
   * @param {{light: number[], setup: ShadowSetup}} options.start the first light and its setup
   * @param {import("./lifecycle.js").Lifecycle} options.life the page's: a failed page draws no more
   * @param {(record: FrameRecord) => void} options.onFrame after each drawn frame (recording, HUD)
   */
  constructor({ navigation, light, shadows, camera, tau, start, life, onFrame }) {
    this.navigation = navigation;
    this.light = light;
    this.shadows = shadows;
    this.camera = camera;
    this.tau = tau;
    this.life = life;
    this.onFrame = onFrame;
    /** @type {[Pane | null, Pane | null]} [gigan, cloud or null], set once they exist */
    this.panes = [null, null];
    this.applied = start; // the light frames draw
    /** @type {string | null} */
    this.prevKey = null;
    /** @type {import("./record.js").Replay | null} */
    this.driver = null;
    this.hold = false; // no new requests (an autoplay's drain, and after it until a person's input)
    /** @type {(() => void)[]} */
    this.drained = [];
    /** @type {History<FrameRecord>} every frame drawn, the last FRAMES_KEPT kept */
    this.frames = new History("frames", FRAMES_KEPT);
    /** @type {History<MapRecord>} every GI map made, both panes', in the order they landed */
    this.maps = new History("maps", MAPS_KEPT);
    this.tick = this.tick.bind(this);
  }

  start() {
    requestAnimationFrame(this.tick);
  }

  /** @param {number} now */
  tick(now) {
    if (this.life.error) return; // stopped (a failed shadow fetch, say)
    try {
      this.step(now);
    } catch (e) {
      this.life.fail(e);
      return;
    }
    requestAnimationFrame(this.tick);
  }

  /**
   * The frame's local and GI cameras (WebGL's Float32Array matrices) at `pose`, and the light.
   * @param {import("./camera.js").Pose} pose
   * @returns {Frame}
   */
  frameAt(pose) {
    const c = this.camera;
    const cam = { eye: pose.eye, target: pose.target, up: c.up, near: c.near, far: c.far };
    const { light, setup } = this.applied;
    return { local: forGL({ ...cam, fov: c.local_fov }), gi: forGL({ ...cam, fov: c.gi_fov }), light, shadow: setup };
  }

  /**
   * What a map depends on: the view and the light drawn.
   * @param {import("./camera.js").Pose} pose
   */
  key(pose) {
    return JSON.stringify([pose.eye, pose.target, this.applied.light]);
  }

  /** @param {number} now */
  step(now) {
    const index = this.frames.count;
    let replayed = this.driver ? this.driver.step(now) : null;
    if (replayed === -1) this.driver = replayed = null;
    const pose = this.navigation.pose();
    const requested = this.light.value;
    const setup = this.shadows.get(requested, (e) => this.life.fail(e));
    if (setup) this.applied = { light: requested, setup };
    const key = this.key(pose);
    const moving = key !== this.prevKey;
    const panes = this.panes.filter((p) => p !== null);
    /** @param {Pane} p */
    const due = (p) => p.landed() || (!this.hold && p.wants(index, key, false));
    if (replayed === null && !moving && !panes.some(due)) {
      this.checkDrained();
      return;
    }
    this.prevKey = key;
    const t0 = performance.now();
    const frame = this.frameAt(pose);
    const [g, c] = this.panes.map((p) => p && p.frame(index, key, moving, frame, this.tau, this.hold));
    if (!g) throw new Error("the frame loop started before GIGAN's pane");
    const { eye, target, up, fov, near, far } = frame.local;
    /** @type {FrameRecord} */
    const record = {
      t: now, frame_ms: performance.now() - t0, gigan_di: g.di, ...(c ? { cloud_di: c.di } : {}),
      gigan: g.stats, cloud: c ? c.stats : null, replay: replayed,
      camera: { eye, target, up, fov, near, far }, light: [...frame.light],
    };
    for (const map of [g.map, c?.map]) if (map) this.maps.push(map);
    this.frames.push(record);
    this.onFrame(record);
    this.checkDrained();
  }

  /**
   * Play a Replay (one of its frames per drawn frame); resolves when it is done.
   * @param {import("./record.js").Replay} replay
   */
  play(replay) {
    if (this.driver) throw new Error("replay: another replay is playing");
    this.driver = replay;
    return replay.done;
  }

  // Resolves once no request is in flight, sending no new ones meanwhile (and after, until release()).
  /** @returns {Promise<void>} */
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
