// The viewer: both systems fly the scene's camera path, each on its own canvas (own WebGL2 context, as two
// separate clients would), and the HUD shows their per-stage times (performance.now, after a GPU sync).
// window.viewer holds everything measured, for bench web and the tests.

import { context, median, readFloats } from "./glutil.js";
import { SceneRenderer } from "./scene.js";
import { GiganSystem } from "./gigan.js";
import { CloudSystem } from "./cloud.js";

const GIGAN_STAGES = ["gi_render", "inference", "warp", "blend"];
const CLOUD_STAGES = ["transmission", "server", "decode", "warp", "blend"];
const viewer = (window.viewer = { done: false, error: null, maps: [], frames: [], info: {} });
const params = new URLSearchParams(location.search);

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

// onnxruntime-web: the WebGPU build when the browser has an adapter (and --backend allows it), else the wasm-only
// build (half the wasm to compile). Returns the module and the session.
async function session(config) {
  const adapter = config.backend !== "wasm" && "gpu" in navigator && (await navigator.gpu.requestAdapter().catch(() => null));
  if (config.backend === "webgpu" && !adapter) throw new Error("--backend webgpu: this browser has no WebGPU adapter");
  const ort = await import(adapter ? "/npm/onnxruntime-web/ort.all.min.mjs" : "/npm/onnxruntime-web/ort.wasm.min.mjs");
  ort.env.wasm.wasmPaths = "/npm/onnxruntime-web/";
  ort.env.wasm.numThreads = crossOriginIsolated ? config.threads : 1;
  const model = await (await fetch("/assets/model/model.onnx")).arrayBuffer();
  const providers = adapter ? ["webgpu", "wasm"] : ["wasm"];
  // GIModel's settings: all graph optimisations, intra-op threads that do not spin after a run (they would hold
  // the cores the next WebGL passes need)
  const options = { executionProviders: providers, graphOptimizationLevel: "all",
    extra: { session: { intra_op: { allow_spinning: "0" } } } };
  const s = await ort.InferenceSession.create(model, options);
  viewer.info.backend = adapter ? "webgpu" : "wasm";
  viewer.info.wasm_threads = ort.env.wasm.numThreads;
  return { ort, session: s };
}

// ---- HUD -------------------------------------------------------------------------------------------------
function row(name, last, values) {
  const f = (v) => (Number.isFinite(v) ? v.toFixed(1) : "—");
  return `<tr><td>${name}</td><td>${f(last)}</td><td>${f(median(values))}</td></tr>`;
}

function hud(id, stages, maps, di) {
  const rows = stages.map((s) => row(s, maps.at(-1)?.stages[s], maps.map((m) => m.stages[s]).filter(Number.isFinite)));
  rows.push(row("<b>total</b>", maps.at(-1)?.total, maps.map((m) => m.total)));
  rows.push(row("di (shared, not counted)", di.at(-1), di));
  document.getElementById(id).innerHTML =
    `<tr><th>stage (ms)</th><th>last</th><th>median</th></tr>${rows.join("")}<tr><td>maps</td><td colspan=2>${maps.length}</td></tr>`;
}

function showHud() {
  const g = viewer.maps.filter((m) => m.system === "gigan");
  const c = viewer.maps.filter((m) => m.system === "cloud_baking");
  hud("hud-gigan", GIGAN_STAGES, g, viewer.frames.map((f) => f.gigan_di));
  hud("hud-cloud", CLOUD_STAGES, c, viewer.frames.map((f) => f.cloud_di).filter(Number.isFinite));
  const ratio = median(c.map((m) => m.total)) / median(g.map((m) => m.total));
  document.getElementById("ratio").textContent = Number.isFinite(ratio)
    ? `median total: cloud baking / GIGAN = ${ratio.toFixed(2)}` : "";
  document.getElementById("status").textContent =
    `frame ${viewer.frames.length} / ${viewer.config.frames} · ${viewer.info.backend} · ${viewer.info.renderer}`;
}

// ---- one system's frame ----------------------------------------------------------------------------------
function timed(fn) {
  const t0 = performance.now();
  fn();
  return performance.now() - t0;
}

async function main() {
  const config = (viewer.config = { ...(await json("/config.json")), ...Object.fromEntries(params) });
  for (const k of ["frames", "every", "tau", "spp", "threads", "resolution"]) config[k] = Number(config[k]);
  config.cloud = String(config.cloud) === "true";
  const [scene, path, modelConfig, bin] = await Promise.all([
    json("/assets/scene.json"), json("/assets/path.json"), json("/assets/model/model.json"),
    fetch("/assets/scene.bin").then((r) => r.arrayBuffer()),
  ]);
  config.light_moves = new Set(path.frames.map((f) => f.light.join(","))).size > 1;
  const glG = context(document.getElementById("gigan"));
  const glC = context(document.getElementById("cloud"));
  const dbg = glG.getExtension("WEBGL_debug_renderer_info");
  viewer.info.renderer = dbg ? glG.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : glG.getParameter(glG.RENDERER);
  viewer.info.cross_origin_isolated = crossOriginIsolated;
  viewer.info.triangles = scene.triangles;
  const sceneG = new SceneRenderer(glG, scene, bin);
  const sceneC = new SceneRenderer(glC, scene, bin);
  const first = path.frames[0];
  const cloud = config.cloud ? new CloudSystem(glC, sceneC, config) : null;
  if (!cloud) document.getElementById("cloud-off").hidden = false;
  // cloud baking's first request (frame 0's) goes out now: its server works while the page sets up GIGAN
  if (cloud) cloud.request(first, 0);
  const { ort, session: s } = await session(config);
  const gigan = new GiganSystem(glG, sceneG, modelConfig, s, ort);

  // warm-up, untimed (as the Python clients' warm_up): every shader compiled and run once, onnxruntime's first
  // runs (lazy initialisation) done; GIGAN's map from it is dropped
  await gigan.produce(first);
  await gigan.infer(gigan.input);
  const diWarmG = sceneG.renderDI(first);
  gigan.warp(first, diWarmG);
  gigan.blend(diWarmG, config.tau);
  if (cloud) cloud.warmUp(first, sceneC.renderDI(first));
  let parityInput = null; // the first map's input tensor: bench web times session.run on it against Python
  viewer.infer = async () => (await gigan.infer(parityInput)).ms;

  const frames = Math.min(config.frames, path.frames.length);
  let pendingG = null; // a new map's stages until its first frame is composed
  let pendingC = null;
  for (let f = 0; f < frames; f++) {
    const frame = path.frames[f];
    const rec = { frame: f };
    // GIGAN: a map every k frames, made here (synchronously, as gigan-client does)
    if (f % config.every === 0) {
      const made = await gigan.produce(frame, !viewer.parity);
      pendingG = { system: "gigan", frame: f, stages: made.stages };
      if (!viewer.parity) {
        parityInput = gigan.input.slice();
        viewer.parity = { ...Object.fromEntries(Object.entries(made.buffers).map(([k, v]) => [k, b64(v)])),
          display: b64(made.display), resolution: gigan.n, light: frame.light,
          camera: { eye: frame.gi.eye, target: frame.gi.target, fov: frame.gi.fov, near: frame.gi.near, far: frame.gi.far } };
      }
    }
    let diG;
    rec.gigan_di = timed(() => { diG = sceneG.renderDI(frame); glSyncDI(glG, diG); });
    rec.gigan_warp = timed(() => gigan.warp(frame, diG));
    rec.gigan_blend = timed(() => gigan.blend(diG, config.tau));
    if (pendingG) {
      const s = pendingG.stages;
      s.warp = s.bind + rec.gigan_warp;
      s.blend = rec.gigan_blend;
      pendingG.total = GIGAN_STAGES.reduce((a, k) => a + s[k], 0);
      viewer.maps.push(pendingG);
      pendingG = null;
    }
    // cloud baking: a request every k frames (one in flight), the first map awaited
    if (cloud) {
      if (f % config.every === 0) cloud.request(frame, f);
      const got = await cloud.take(!cloud.bound);
      if (got) pendingC = { system: "cloud_baking", ...got };
      let diC;
      rec.cloud_di = timed(() => { diC = sceneC.renderDI(frame); glSyncDI(glC, diC); });
      rec.cloud_warp = timed(() => cloud.warp(frame, diC));
      rec.cloud_blend = timed(() => cloud.blend(diC, config.tau));
      if (pendingC) {
        const s = pendingC.stages;
        s.warp = s.bind + rec.cloud_warp;
        s.blend = rec.cloud_blend;
        pendingC.total = CLOUD_STAGES.reduce((a, k) => a + s[k], 0);
        viewer.maps.push(pendingC);
        pendingC = null;
      }
    }
    viewer.frames.push(rec);
    showHud();
    await new Promise((r) => setTimeout(r, 0)); // let the page paint and the fetch progress
  }
  // the last frame of each canvas and its DI alone, for the checks that the canvases show GI (bench web, tests)
  viewer.snapshot = () => ({ gigan: snapshot(glG, sceneG.diTarget), cloud: cloud ? snapshot(glC, sceneC.diTarget) : null });
  viewer.done = true;
  showHud();
}

function snapshot(gl, diTarget) {
  const n = diTarget.w;
  const canvas = new Uint8Array(n * n * 4);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.readPixels(0, 0, n, n, gl.RGBA, gl.UNSIGNED_BYTE, canvas);
  return { canvas: b64(canvas), di: b64(readFloats(gl, diTarget, 0)), resolution: n };
}

function glSyncDI(gl, t) {
  const px = new Float32Array(4);
  gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
  gl.readBuffer(gl.COLOR_ATTACHMENT0);
  gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.FLOAT, px);
}

main().catch((e) => {
  viewer.error = String(e && e.stack ? e.stack : e);
  viewer.done = true;
  document.getElementById("status").textContent = `error: ${e}`;
  console.error(e);
});
