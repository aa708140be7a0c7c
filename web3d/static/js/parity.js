// What the checks against the Python clients read of the page (bench web, the tests; web3d.parity): both canvases'
// last frames with their DI, and GIGAN's untimed warm-up, whose map's buffers, prediction and camera are the
// parity check's input and whose input tensor viewer.infer() times session.run on.

import { readFloats } from "./glutil.js";

/** @typedef {import("./glutil.js").GL} GL */
/** @typedef {import("./glutil.js").Target} Target */
/**
 * GIGAN's first map as the parity check reads it: its G-buffers and prediction (base64 float32), its GI camera
 * and light.
 * @typedef {Record<string, unknown> & {display: string, resolution: number, light: number[]}} Parity
 */

/**
 * A typed array's bytes as base64.
 * @param {ArrayBufferView} typed
 */
export function b64(typed) {
  const bytes = new Uint8Array(typed.buffer, typed.byteOffset, typed.byteLength);
  let s = "";
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

/**
 * A canvas's last frame and its DI alone, for the checks that the canvases show GI.
 * @param {GL} gl
 * @param {Target} diTarget
 */
export function snapshot(gl, diTarget) {
  const n = diTarget.w;
  const canvas = new Uint8Array(n * n * 4);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.readPixels(0, 0, n, n, gl.RGBA, gl.UNSIGNED_BYTE, canvas);
  return { canvas: b64(canvas), di: b64(readFloats(gl, diTarget, 0)), resolution: n };
}

/**
 * GIGAN's warm-up, untimed (as the Python clients' warm_up): every shader compiled and run once, onnxruntime's
 * first run done. Its map (at the first frame's view) stays bound until the first timed one lands. Returns the
 * parity check's input and a timed session.run on its input tensor.
 * @param {import("./gigan.js").GiganSystem} gigan
 * @param {import("./pane.js").Pane<any>} pane
 * @param {import("./scene.js").Frame} frame
 * @param {number} tau
 * @returns {Promise<{parity: Parity, infer: () => Promise<number>}>}
 */
export async function warmUp(gigan, pane, frame, tau) {
  const req = gigan.request(frame, true);
  gigan.join(req, await req.run);
  pane.shown = { index: 0, captured: req.posted };
  const di = pane.scene.renderDI(frame);
  gigan.warp(frame, di);
  gigan.blend(di, tau);
  if (!req.kept?.display) throw new Error("GIGAN's warm-up kept no buffers");
  const { buffers, display, input } = req.kept;
  const gi = frame.gi;
  const parity = { ...Object.fromEntries(Object.entries(buffers).map(([k, v]) => [k, b64(v)])),
    display: b64(display), resolution: gigan.n, light: frame.light,
    camera: { eye: gi.eye, target: gi.target, fov: gi.fov, near: gi.near, far: gi.far } };
  return { parity, infer: async () => (await gigan.infer(input.slice())).ms };
}
