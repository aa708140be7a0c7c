// window.viewer: the page's API for bench web and the tests (docs/architecture.md, Web3D viewer). It keeps no
// state of its own: each member reads or drives the part of the page that owns it (the lifecycle, the frame loop's
// records, the controls, the light, the cloud route, the recorder), once main.js has attached them.

import { clampLight, withMatrices } from "./camera.js";
import { Replay } from "./record.js";
import { snapshot } from "./parity.js";

/** @typedef {import("./record.js").PathDoc} PathDoc */
/** @typedef {import("./camera.js").Pose} Pose */
/**
 * The page's parts the API drives (main.js makes them).
 * @typedef {object} Parts
 * @property {import("./config.js").Config} config
 * @property {import("./scene.js").SceneHeader} scene
 * @property {import("./loop.js").FrameLoop} loop
 * @property {import("./controls.js").Navigation} navigation
 * @property {import("./light.js").LightInput} lightInput
 * @property {import("./light.js").ShadowSetups} shadows
 * @property {import("./record.js").Recorder} recorder
 * @property {import("./hud.js").Hud} hud
 * @property {HTMLButtonElement} recordButton
 * @property {import("./cloud_route.js").CloudRoute | null} route
 * @property {{gl: WebGL2RenderingContext, scene: import("./scene.js").SceneRenderer}} gigan GIGAN's canvas
 * @property {{gl: WebGL2RenderingContext, scene: import("./scene.js").SceneRenderer,
 *   system: import("./cloud.js").CloudSystem} | null} cloud the cloud's canvas (null: off)
 * @property {{parity: import("./parity.js").Parity, infer: () => Promise<number>}} warmUp GIGAN's first map
 */

export class Viewer {
  /** @type {Parts | null} */
  #parts = null;

  /**
   * @param {import("./lifecycle.js").Lifecycle} life
   * @param {Record<string, unknown>} info the backend, renderer, wasm threads, cross-origin isolation
   */
  constructor(life, info) {
    this.life = life;
    this.info = info;
  }

  /** @param {Parts} parts */
  attach(parts) {
    this.#parts = parts;
  }

  /** @returns {Parts} */
  get #page() {
    if (!this.#parts) throw new Error("the viewer is still loading: wait for viewer.ready");
    return this.#parts;
  }

  get ready() {
    return this.life.ready;
  }

  get done() {
    return this.life.done;
  }

  get error() {
    return this.life.error;
  }

  get config() {
    return this.#parts?.config ?? null;
  }

  /** Every frame drawn (a History: count, since(i), last()); null while loading. */
  get frames() {
    return this.#parts?.loop.frames ?? null;
  }

  /** Every GI map made, both panes' (a History); null while loading. */
  get maps() {
    return this.#parts?.loop.maps ?? null;
  }

  get profile() {
    return this.#parts?.route?.profile ?? null;
  }

  get store() {
    return this.#parts?.route?.store ?? null;
  }

  get parity() {
    return this.#parts?.warmUp.parity ?? null;
  }

  /** One timed session.run (ms) on GIGAN's first map's input. */
  infer() {
    return this.#page.warmUp.infer();
  }

  camera() {
    const { navigation, scene } = this.#page;
    const cam = scene.camera;
    return withMatrices({ ...navigation.pose(), up: cam.up, fov: cam.local_fov, near: cam.near, far: cam.far });
  }

  /** @param {Partial<Pose>} pose */
  setCamera(pose) {
    const navigation = this.#page.navigation;
    navigation.set({ ...navigation.pose(), ...pose });
    return this.camera();
  }

  light() {
    return [...this.#page.lightInput.value];
  }

  /** @param {number[]} light */
  setLight(light) {
    return [...this.#page.lightInput.set(light)];
  }

  /** @param {string} name */
  setProfile(name) {
    this.#route("setProfile").set("profile", name);
  }

  /** @param {string} name */
  setStore(name) {
    this.#route("setStore").set("store", name);
  }

  /** @param {string} call */
  #route(call) {
    const route = this.#page.route;
    if (!route) throw new Error(`${call}: the cloud side is off`);
    return route;
  }

  /** @param {boolean} on */
  record(on) {
    const { recorder, recordButton, hud } = this.#page;
    recorder.set(Boolean(on));
    recordButton.textContent = recorder.on ? "Stop and download" : "Record";
    hud.show(); // now: no frame may come until something changes
  }

  recording() {
    return this.#page.recorder.doc();
  }

  /**
   * Play a path file through setCamera and setLight, one of its frames per drawn frame (`realtime`: the latest
   * whose t_ms has passed), its lights' shadow setups fetched first; resolves once its last frame is drawn.
   * @param {PathDoc} doc
   * @param {{realtime?: boolean}} [options]
   */
  async replay(doc, { realtime = false } = {}) {
    const { shadows, scene, loop } = this.#page;
    const replay = new Replay(doc, realtime, (f) => {
      this.setCamera(f.camera);
      this.setLight(f.light);
    });
    await shadows.prefetch(doc.frames.map((f) => clampLight(f.light, scene.light_range)));
    return loop.play(replay);
  }

  /** Both canvases' last frames and their DI; the cloud pane's also names the stored map it shows. */
  snapshot() {
    const { gigan, cloud } = this.#page;
    return {
      gigan: snapshot(gigan.gl, gigan.scene.diTarget),
      cloud: cloud ? { ...snapshot(cloud.gl, cloud.scene.diTarget), map: cloud.system.bound?.location } : null,
    };
  }
}
