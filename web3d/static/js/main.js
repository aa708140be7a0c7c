// The viewer: GIGAN (left) and cloud baking (right), each on its own canvas (own WebGL2 context, as two separate
// clients would), both following one camera a person drives (controls.js) under one light (light.js), drawn by
// the frame loop (loop.js) with GI maps that arrive when they are ready (pane.js). window.viewer is the page's API
// for bench web and the tests (docs/architecture.md, Web3D viewer).
//
// URL parameters override /config.json's keys; also ?autoplay=1&frames=N (replay the scripted path's first N
// frames, let the maps in flight land, then viewer.done) and ?record=1 (record from the first frame).

import { context, readFloats } from "./glutil.js";
import { SceneRenderer } from "./scene.js";
import { GiganSystem } from "./gigan.js";
import { CloudSystem } from "./cloud.js";
import { clampLight, withMatrices } from "./camera.js";
import { Navigation } from "./controls.js";
import { LightInput, ShadowSetups } from "./light.js";
import { FrameLoop } from "./loop.js";
import { CLOUD_STAGES, GIGAN_STAGES, Pane } from "./pane.js";
import { Recorder, Replay, download } from "./record.js";
import { showHud } from "./hud.js";
import { openSession } from "./inference.js";

const viewer = (window.viewer = {
  ready: false, done: false, error: null, config: null, info: {}, maps: [], frames: [], parity: null,
  profile: null, store: null,
});
const params = new URLSearchParams(location.search);
const $ = (id) => document.getElementById(id);

async function json(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: ${r.status}`);
  return r.json();
}

function b64(typed) {
  const bytes = new Uint8Array(typed.buffer, typed.byteOffset, typed.byteLength);
  let s = "";
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

async function loadConfig() {
  const config = { ...(await json("/config.json")), ...Object.fromEntries(params) };
  for (const k of ["frames", "every", "tau", "spp", "threads", "resolution"]) config[k] = Number(config[k]);
  config.autoplay = config.autoplay === "1";
  config.record = config.record === "1";
  return config;
}

// The canvas's last frame and its DI alone, for the checks that the canvases show GI (bench web, tests).
function snapshot(gl, diTarget) {
  const n = diTarget.w;
  const canvas = new Uint8Array(n * n * 4);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.readPixels(0, 0, n, n, gl.RGBA, gl.UNSIGNED_BYTE, canvas);
  return { canvas: b64(canvas), di: b64(readFloats(gl, diTarget, 0)), resolution: n };
}

// A select's options from `names` (a person's pick calls `pick`).
function fillSelect(select, names, value, pick) {
  select.innerHTML = names.map((n) => `<option>${n}</option>`).join("");
  select.value = value;
  select.addEventListener("change", () => pick(select.value));
}

// The cloud pane's side: its system, the profile and store selects, the request URL. Null when the cloud is off.
function cloudSide(config, gl, scene, shaders, loop) {
  if (!config.profiles?.length) {
    $("cloud-off").hidden = false;
    $("cloud-settings").hidden = true;
    return null;
  }
  const system = new CloudSystem(gl, scene, config, shaders);
  const choose = (kind, names) => (name) => {
    if (!names.includes(name)) throw new Error(`set${kind}: ${name} is not one of ${names.join(", ")}`);
    viewer[kind.toLowerCase()] = name;
    $(kind.toLowerCase()).value = name;
    loop().panes[1]?.forget(); // a map through the new profile or store at once
  };
  viewer.setProfile = choose("Profile", config.profiles);
  viewer.setStore = choose("Store", config.stores);
  viewer.profile = config.profiles.includes(config.profile) ? config.profile : config.profiles[0];
  viewer.store = config.stores.includes(config.store) ? config.store : config.stores[0];
  fillSelect($("profile"), config.profiles, viewer.profile, viewer.setProfile);
  fillSelect($("store"), config.stores, viewer.store, viewer.setStore);
  const url = () => `/v1/gimap?profile=${encodeURIComponent(viewer.profile)}&store=${encodeURIComponent(viewer.store)}`;
  return { system, url };
}

// GIGAN's warm-up, untimed (as the Python clients' warm_up): every shader compiled and run once, onnxruntime's
// first run done. Its map (at the first frame's view) stays bound until the first timed one lands; its buffers
// are viewer.parity, its input what viewer.infer() times session.run on.
async function warmUp(gigan, pane, frame, tau) {
  const req = gigan.request(frame, true);
  gigan.join(req, await req.run);
  pane.shown = { index: 0, captured: req.posted };
  const di = pane.scene.renderDI(frame);
  gigan.warp(frame, di);
  gigan.blend(di, tau);
  const { buffers, display, input } = req.kept;
  const gi = frame.gi;
  viewer.parity = { ...Object.fromEntries(Object.entries(buffers).map(([k, v]) => [k, b64(v)])),
    display: b64(display), resolution: gigan.n, light: frame.light,
    camera: { eye: gi.eye, target: gi.target, fov: gi.fov, near: gi.near, far: gi.far } };
  viewer.infer = async () => (await gigan.infer(input.slice())).ms;
}

function giganPane(gigan, scene, every) {
  return new Pane({ label: "gigan", system: gigan, scene, stages: GIGAN_STAGES, every, fatal: true, maps: viewer.maps,
    start: (frame) => gigan.request(frame), join: (req, r) => ({ stages: gigan.join(req, r) }) });
}

function cloudPane({ system, url }, scene, every) {
  return new Pane({ label: "cloud_baking", system, scene, stages: CLOUD_STAGES, every, fatal: false, maps: viewer.maps,
    start: (frame) => ({ run: system.request(frame, url()), profile: viewer.profile, store: viewer.store }),
    join: (req, done) => ({ ...system.join(done), profile: req.profile, store: req.store }) });
}

// window.viewer's methods over the page's parts (docs/architecture.md, Web3D viewer).
function api(page) {
  const { scene, navigation, lightInput, shadows, recorder, loop } = page;
  const cam = scene.camera;
  viewer.camera = () =>
    withMatrices({ ...navigation.pose(), up: cam.up, fov: cam.local_fov, near: cam.near, far: cam.far });
  viewer.setCamera = (pose) => {
    navigation.set({ ...navigation.pose(), ...pose });
    return viewer.camera();
  };
  viewer.light = () => [...lightInput.value];
  viewer.setLight = (light) => [...lightInput.set(light)];
  viewer.record = (on) => {
    recorder.set(Boolean(on));
    $("record").textContent = recorder.on ? "Stop and download" : "Record";
    showHud(viewer, recorder.on); // now: no frame may come until something changes
  };
  viewer.recording = () => recorder.doc();
  viewer.replay = async (doc, { realtime = false } = {}) => {
    const apply = (f) => {
      viewer.setCamera(f.camera);
      viewer.setLight(f.light);
    };
    const replay = new Replay(doc, realtime, apply);
    await shadows.prefetch(doc.frames.map((f) => clampLight(f.light, scene.light_range)));
    return loop.play(replay);
  };
  // Both canvases; the cloud pane's also names the stored map it shows (/v1/maps/{sha}).
  viewer.snapshot = () => ({
    gigan: snapshot(page.glG, page.sceneG.diTarget),
    cloud: page.cloud ? { ...snapshot(page.glC, page.sceneC.diTarget), map: page.cloud.system.bound?.location } : null,
  });
}

// What a person does on the page: the Record button, and any input lifts an autoplay's hold on new maps.
function wireInput(page) {
  $("record").addEventListener("click", () => {
    const was = page.recorder.on;
    viewer.record(!was);
    if (was) download(viewer.recording());
  });
  const release = () => page.loop.release();
  for (const type of ["pointerdown", "wheel", "keydown", "input"]) {
    window.addEventListener(type, release, { capture: true });
  }
}

// The page's parts that need no model: both canvases' renderers, the camera and light inputs, the cloud side.
async function parts(config, scene, shaders, bin, path) {
  const glG = context($("gigan"));
  const glC = context($("cloud"));
  const dbg = glG.getExtension("WEBGL_debug_renderer_info");
  const renderer = dbg ? glG.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : glG.getParameter(glG.RENDERER);
  Object.assign(viewer.info, { renderer, cross_origin_isolated: crossOriginIsolated, triangles: scene.triangles });
  const page = { scene, glG, glC, sceneG: new SceneRenderer(glG, scene, bin), sceneC: new SceneRenderer(glC, scene, bin) };
  page.recorder = new Recorder(scene.scene);
  page.shadows = new ShadowSetups();
  const first = path.frames[0];
  const light = clampLight(first.light, scene.light_range);
  await page.shadows.prefetch([light]);
  page.navigation = new Navigation($("stage"), scene.camera, scene.navigation, first.camera);
  page.lightInput = new LightInput(scene.light_range, light, [$("light-x"), $("light-y")], $("stage"));
  page.cloud = cloudSide(config, glC, page.sceneC, shaders, () => page.loop);
  page.loop = new FrameLoop({ viewer, navigation: page.navigation, light: page.lightInput, shadows: page.shadows,
    camera: scene.camera, tau: config.tau, start: { light, setup: page.shadows.get(light) }, fail,
    onFrame: (record, frame) => {
      page.recorder.push(record.t, frame.local, frame.light);
      showHud(viewer, page.recorder.on);
    } });
  return page;
}

async function main() {
  const config = (viewer.config = await loadConfig());
  const [scene, shaders, path, modelConfig, bin] = await Promise.all([
    json("/assets/scene.json"), json("/assets/shaders.json"), json("/assets/path.json"),
    json("/assets/model/model.json"), fetch("/assets/scene.bin").then((r) => r.arrayBuffer()),
  ]);
  const page = await parts(config, scene, shaders, bin, path);
  const loop = page.loop;
  const frame0 = loop.frameAt(page.navigation.pose());
  const cPane = page.cloud && cloudPane(page.cloud, page.sceneC, config.every);
  const { ort, session } = await openSession(config, viewer.info);
  const gigan = new GiganSystem(page.glG, page.sceneG, modelConfig, session, ort, shaders);
  const gPane = giganPane(gigan, page.sceneG, config.every);
  loop.panes = [gPane, cPane];
  await warmUp(gigan, gPane, frame0, config.tau);
  if (cPane) cPane.system.warmUp(frame0, page.sceneC.renderDI(frame0));
  api(page);
  wireInput(page);
  viewer.record(config.record);
  if (config.autoplay) return autoplay(page, { ...path, frames: path.frames.slice(0, config.frames) });
  loop.start();
  viewer.ready = true;
}

// ?autoplay=1: the path replayed from the loop's first frame, the maps in flight landed, then viewer.done (new
// maps wait for a person's input from then on).
async function autoplay(page, doc) {
  await page.shadows.prefetch(doc.frames.map((f) => clampLight(f.light, page.scene.light_range)));
  const played = viewer.replay(doc); // its setups are cached: it plays before the loop's first frame
  page.loop.start();
  viewer.ready = true;
  await played;
  await page.loop.drain();
  viewer.done = true;
  showHud(viewer, page.recorder.on);
}

function fail(e) {
  viewer.error = String(e && e.stack ? e.stack : e);
  viewer.done = true;
  $("status").textContent = `error: ${e}`;
  console.error(e);
}

main().catch(fail);
