// The viewer: GIGAN (left) and cloud baking (right), each on its own canvas (own WebGL2 context, as two separate
// clients would), both following one camera a person drives (controls.js) under one light (light.js), drawn by
// the frame loop (loop.js) with GI maps that arrive when they are ready (pane.js). This module makes the parts and
// wires them; each keeps its own state. window.viewer (api.js) is the page's API for bench web and the tests
// (docs/architecture.md, Web3D viewer); the URL's parameters are config.js's.

import { context } from "./glutil.js";
import { SceneRenderer } from "./scene.js";
import { GiganSystem } from "./gigan.js";
import { CloudSystem } from "./cloud.js";
import { clampLight } from "./camera.js";
import { Navigation } from "./controls.js";
import { LightInput, ShadowSetups } from "./light.js";
import { FrameLoop } from "./loop.js";
import { CLOUD_STAGES, GIGAN_STAGES, Pane } from "./pane.js";
import { Recorder, download } from "./record.js";
import { Hud } from "./hud.js";
import { openSession } from "./inference.js";
import { json, loadConfig } from "./config.js";
import { byId } from "./dom.js";
import { CloudRoute } from "./cloud_route.js";
import { Lifecycle } from "./lifecycle.js";
import { Viewer } from "./api.js";
import { warmUp } from "./parity.js";

/** @typedef {import("./config.js").Config} Config */
/** @typedef {import("./scene.js").SceneHeader} SceneHeader */
/** @typedef {import("./glutil.js").Shaders} Shaders */
/** @typedef {import("./record.js").PathDoc} PathDoc */

const life = new Lifecycle(byId("status", HTMLElement));
/** @type {Record<string, unknown>} */
const info = {};
const viewer = new Viewer(life, info);
Object.assign(window, { viewer });

/**
 * The cloud requests' route (the profile and store selects); null when the cloud is off.
 * @param {Config} config
 * @param {FrameLoop} loop
 */
function cloudRoute(config, loop) {
  if (!config.profiles?.length) {
    byId("cloud-off", HTMLElement).hidden = false;
    byId("cloud-settings", HTMLElement).hidden = true;
    return null;
  }
  const selects = { profile: byId("profile", HTMLSelectElement), store: byId("store", HTMLSelectElement) };
  return new CloudRoute(config, selects, () => loop.panes[1]?.forget()); // a map through the new route at once
}

/**
 * @param {GiganSystem} gigan
 * @param {SceneRenderer} scene
 * @param {number} every
 */
function giganPane(gigan, scene, every) {
  return new Pane({ label: "gigan", system: gigan, scene, stages: GIGAN_STAGES, every, fatal: true,
    start: (frame) => gigan.request(frame),
    join: (req, r) => ({ stages: gigan.join(req, r) }) });
}

/**
 * @param {CloudSystem} system
 * @param {CloudRoute} route
 * @param {SceneRenderer} scene
 * @param {number} every
 */
function cloudPane(system, route, scene, every) {
  return new Pane({ label: "cloud_baking", system, scene, stages: CLOUD_STAGES, every, fatal: false,
    start: (frame) => ({ run: system.request(frame, route.url()), profile: route.profile, store: route.store }),
    join: (req, done) => ({ ...system.join(done), profile: req.profile, store: req.store }) });
}

/**
 * What a person does on the page: the Record button, and any input lifts an autoplay's hold on new maps.
 * @param {import("./api.js").Parts} parts
 */
function wireInput(parts) {
  parts.recordButton.addEventListener("click", () => {
    const was = parts.recorder.on;
    viewer.record(!was);
    if (was) download(viewer.recording());
  });
  const release = () => parts.loop.release();
  for (const type of ["pointerdown", "wheel", "keydown", "input"]) {
    window.addEventListener(type, release, { capture: true });
  }
}

/**
 * The page's parts that need no model: both canvases' renderers, the camera and light inputs, the frame loop, the
 * cloud side, the recorder and the HUD.
 * @param {Config} config
 * @param {SceneHeader} scene
 * @param {Shaders} shaders
 * @param {ArrayBuffer} bin
 * @param {PathDoc} path
 */
async function parts(config, scene, shaders, bin, path) {
  const glG = context(byId("gigan", HTMLCanvasElement));
  const glC = context(byId("cloud", HTMLCanvasElement));
  const dbg = glG.getExtension("WEBGL_debug_renderer_info");
  const renderer = dbg ? glG.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : glG.getParameter(glG.RENDERER);
  Object.assign(info, { renderer, cross_origin_isolated: crossOriginIsolated, triangles: scene.triangles });
  const shadows = new ShadowSetups();
  const first = path.frames[0];
  const light = clampLight(first.light, scene.light_range);
  await shadows.prefetch([light]);
  const setup = shadows.get(light, (e) => life.fail(e));
  if (!setup) throw new Error("the first light's shadow setup did not arrive");
  const stage = byId("stage", HTMLElement);
  const navigation = new Navigation(stage, scene.camera, scene.navigation, first.camera);
  const sliders = [byId("light-x", HTMLInputElement), byId("light-y", HTMLInputElement)];
  const lightInput = new LightInput(scene.light_range, light, sliders, stage);
  const recorder = new Recorder(scene.scene, config.record_frames_max);
  const loop = new FrameLoop({ navigation, light: lightInput, shadows, camera: scene.camera, tau: config.tau,
    start: { light, setup }, life, onFrame: (record) => {
      recorder.push(record.t, record.camera, record.light);
      hud.show();
    } });
  const gigan = { gl: glG, scene: new SceneRenderer(glG, scene, bin) };
  const sceneC = new SceneRenderer(glC, scene, bin);
  const route = cloudRoute(config, loop);
  const cloud = route && { gl: glC, scene: sceneC, system: new CloudSystem(glC, sceneC, config, shaders) };
  const hud = new Hud({ loop, recorder, route, info });
  return { config, scene, loop, navigation, lightInput, shadows, recorder, hud, route, gigan, cloud,
    recordButton: byId("record", HTMLButtonElement) };
}

async function main() {
  const config = await loadConfig(new URLSearchParams(location.search));
  const [scene, shaders, path, modelConfig, bin] = await Promise.all([
    json("/assets/scene.json"), json("/assets/shaders.json"), json("/assets/path.json"),
    json("/assets/model/model.json"), fetch("/assets/scene.bin").then((r) => r.arrayBuffer()),
  ]);
  const made = await parts(config, scene, shaders, bin, path);
  const { loop, cloud, route } = made;
  const frame0 = loop.frameAt(made.navigation.pose());
  const cPane = cloud && route && cloudPane(cloud.system, route, cloud.scene, config.every);
  const { ort, session } = await openSession(config, info);
  const gigan = new GiganSystem(made.gigan.gl, made.gigan.scene, modelConfig, session, ort, shaders);
  const gPane = giganPane(gigan, made.gigan.scene, config.every);
  loop.panes = [gPane, cPane];
  const first = await warmUp(gigan, gPane, frame0, config.tau);
  if (cloud) cloud.system.warmUp(frame0, cloud.scene.renderDI(frame0));
  const page = { ...made, warmUp: first };
  viewer.attach(page);
  wireInput(page);
  viewer.record(config.record);
  if (config.autoplay) return autoplay(page, { ...path, frames: path.frames.slice(0, config.frames) });
  loop.start();
  life.ready = true;
}

/**
 * ?autoplay=1: the path replayed from the loop's first frame, the maps in flight landed, then viewer.done (new
 * maps wait for a person's input from then on).
 * @param {import("./api.js").Parts} page
 * @param {PathDoc} doc
 */
async function autoplay(page, doc) {
  await page.shadows.prefetch(doc.frames.map((f) => clampLight(f.light, page.scene.light_range)));
  const played = viewer.replay(doc); // its setups are cached: it plays before the loop's first frame
  page.loop.start();
  life.ready = true;
  await played;
  await page.loop.drain();
  life.done = true;
  page.hud.show();
}

main().catch((e) => life.fail(e));
