// GIGAN in the browser (paper III): DI + G-buffers at the GI camera -> the ONNX generator (onnxruntime-web)
// -> the structure-aware warp (Algorithm 1, eq. 5) and eq. 1's blend in shaders. The encoding is
// gigan_local.preprocess's, the warp gigan_local.warp's: depth test with slope slack, bilinear taps that drop
// out when they fail it, and the current DI plus the map's coarse indirect light where no tap passes. The warp's
// shaders are the desktop GL warp's (gigan_local.gl_warp), from shaders.json; the map's textures have image rows.

import { copyFlipped, pass, programs, readFloats, sync, target, texture } from "./glutil.js";
import { Blend } from "./blend.js";
import { PushPull } from "./fill.js";

/** @typedef {import("./glutil.js").Target} Target */
/** @typedef {import("./scene.js").Frame} Frame */
/** @typedef {typeof import("onnxruntime-web")} Ort */
/**
 * What the page reads of model.json (gigan_local.export): the resolution and the input's buffers and depth scale.
 * @typedef {{resolution: number, input: {buffers: string[], depth_scale: number}}} ModelConfig
 */
/**
 * A map's first half (request): the frame, its stages so far (ms), what the parity check keeps (with `keep`: the
 * G-buffers, the input and, once joined, the decoded map tone-mapped), session.run's promise and when it was posted.
 * @typedef {{frame: Frame, stages: {gi_render: number, encode: number},
 *   kept: {buffers: Record<string, Float32Array>, input: Float32Array, display?: Float32Array} | null,
 *   run: Promise<{y: Float32Array, ms: number}>, posted: number}} GiganRequest
 */

const PROGRAMS = /** @type {const} */ (["structure_slack", "structure_coarse", "structure_mean", "structure_warp",
  "pull", "push", "encode", "decode"]);

export class GiganSystem {
  /**
   * @param {import("./glutil.js").GL} gl
   * @param {import("./scene.js").SceneRenderer} scene
   * @param {ModelConfig} modelConfig
   * @param {import("onnxruntime-web").InferenceSession} session
   * @param {Ort} ort
   * @param {import("./glutil.js").Shaders} shaders
   */
  constructor(gl, scene, modelConfig, session, ort, shaders) {
    this.gl = gl;
    this.scene = scene;
    this.session = session;
    this.ort = ort;
    this.spec = modelConfig.input; // buffers, depth_scale
    const n = (this.n = modelConfig.resolution);
    if (n !== scene.n) throw new Error(`the model runs at ${n}² but the scene renders ${scene.n}²`);
    this.progs = programs(gl, shaders, PROGRAMS);
    this.uniforms = shaders.structure; // the depth test's tolerance, the coarse level's step
    this.blender = new Blend(gl, shaders);
    /** @type {(w: number, h: number, formats?: number[]) => Target} */
    const float = (w, h, formats = [gl.RGBA32F]) => target(gl, w, h, formats, { depth: false });
    this.giMap = float(n, n, [gl.RGBA32F, gl.RGBA32F]); // radiance, indirect light; image rows
    this.output = texture(gl, n, 3 * n, gl.R32F); // the generator's output planes, stacked
    this.channels = shaders.encode.channels;
    this.encoded = float(n, n, Array(shaders.encode.targets).fill(gl.RGBA32F));
    this.encodedReads = this.encoded.textures.map(() => new Float32Array(n * n * 4));
    // the bound map's GI-camera depth, image rows: the G-buffer target is rendered anew by the next request while
    // this map is still warped
    this.mapDepth = float(n, n, [gl.R32F]);
    this.planes = float(n, n, [gl.RG32F]);
    const coarse = Math.ceil(n / this.uniforms.u_step);
    this.fill = new PushPull(gl, { pull: this.progs.pull, push: this.progs.push }, coarse, coarse, 1); // + block sums
    this.mean = float(1, 1);
    this.warped = float(n, n);
    /** @type {{wRow: number[], near: number, viewProj: Float32Array, coarse: Target} | null} */
    this.bound = null;
  }

  // The frame's GI-camera buffers read back as they are (rows bottom-up, RGBA): the parity check's input.
  readBuffers() {
    const t = this.scene.giTarget;
    /** @type {[string, number][]} */
    const attachments = [["albedo", 0], ["normal", 1], ["depth", 3], ["di", 4]];
    return Object.fromEntries(attachments.map(([k, a]) => [k, readFloats(this.gl, t, a)]));
  }

  // gigan_local.preprocess.frame_to_input on the GPU (the encoding shader, 4 channels per target), read back and
  // reordered to NCHW with rows top-down (GL's are bottom-up), into a new array (the inference takes it over).
  encode() {
    const gl = this.gl;
    const gi = this.scene.giTarget;
    pass(gl, this.progs.encode, this.encoded,
      { u_albedo: gi.textures[0], u_normal: gi.textures[1], u_depth: gi.textures[3], u_di: gi.textures[4] },
      { u_depth_scale: this.spec.depth_scale });
    const n = this.n;
    const plane = n * n;
    const channels = this.channels;
    const out = new Float32Array(channels * plane);
    this.encoded.textures.forEach((_, a) => {
      const px = readFloats(gl, this.encoded, a, this.encodedReads[a]);
      for (let k = 0; k < 4 && 4 * a + k < channels; k++) {
        const base = (4 * a + k) * plane;
        for (let row = 0; row < n; row++) {
          const src = (n - 1 - row) * n * 4 + k;
          const dst = base + row * n;
          for (let col = 0; col < n; col++) out[dst + col] = px[src + 4 * col];
        }
      }
    });
    return out;
  }

  // The generator's output (3xHxW in [-1, 1]) to linear radiance (gigan_local.preprocess.output_to_radiance) and
  // its indirect light over the GI camera's DI, in a shader, into the GI map's textures (image rows).
  /** @param {Float32Array} y */
  decode(y) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.output);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, this.n, 3 * this.n, gl.RED, gl.FLOAT, y);
    const gi = this.scene.giTarget;
    pass(gl, this.progs.decode, this.giMap, { u_y: this.output, u_di: gi.textures[4], u_albedo: gi.textures[0] });
  }

  // The decoded GI map tone-mapped (gicore.tonemap), HxWx3 in image rows: what the parity check compares with
  // tonemap(GIModel.predict(...)).
  display() {
    const px = readFloats(this.gl, this.giMap, 0);
    const out = new Float32Array(this.n * this.n * 3);
    for (let o = 0; o < this.n * this.n; o++) {
      for (let k = 0; k < 3; k++) {
        const x = Math.max(px[o * 4 + k], 0);
        out[o * 3 + k] = Math.pow(x / (1 + x), 1 / 2.2);
      }
    }
    return out;
  }

  // session.run on a tensor (its buffer moves to onnxruntime-web's proxy worker: the caller keeps no view of it).
  /**
   * @param {Float32Array} tensor
   * @returns {Promise<{y: Float32Array, ms: number}>}
   */
  async infer(tensor) {
    const n = this.n;
    const input = new this.ort.Tensor("float32", tensor, [1, tensor.length / (n * n), n, n]);
    const feeds = { [this.session.inputNames[0]]: input };
    const t0 = performance.now();
    const result = await this.session.run(feeds);
    const ms = performance.now() - t0;
    return { y: /** @type {Float32Array} */ (result[this.session.outputNames[0]].data), ms };
  }

  // A map's first half, at request time: DI + G-buffers at the GI camera, encoded and read back, and session.run
  // started (it runs in the worker). With `keep`, also the raw buffers and the input (the parity check's).
  /**
   * @param {Frame} frame
   * @param {boolean} [keep]
   * @returns {GiganRequest}
   */
  request(frame, keep = false) {
    let t0 = performance.now();
    sync(this.gl, this.scene.renderGI(frame), 0);
    const giRender = performance.now() - t0;
    t0 = performance.now();
    const tensor = this.encode();
    const stages = { gi_render: giRender, encode: performance.now() - t0 };
    const kept = keep ? { buffers: this.readBuffers(), input: tensor.slice() } : null;
    return { frame, stages, kept, run: this.infer(tensor), posted: performance.now() };
  }

  // Its second half, once session.run is done: the output decoded into the GI map and bound to the request's GI
  // camera. Stages: inference (encoding, the run as the page waited for it, decoding), session_run, bind.
  /**
   * @param {GiganRequest} request
   * @param {{y: Float32Array, ms: number}} result
   */
  join(request, { y, ms }) {
    const waited = performance.now() - request.posted;
    const t0 = performance.now();
    this.decode(y);
    sync(this.gl, this.giMap, 0);
    const decode = performance.now() - t0;
    const t1 = performance.now();
    this.bind(request.frame);
    const bind = performance.now() - t1;
    if (request.kept) request.kept.display = this.display();
    const s = request.stages;
    return { gi_render: s.gi_render, inference: s.encode + waited + decode, session_run: ms, bind };
  }

  // Per map (gigan_local.gl_warp.GLStructureWarp.bind): the map's depth copied in image rows, its depth planes,
  // the coarse fallback level (block means of the indirect light, push-pull filled) and its mean; the GI camera's
  // projection row.
  /** @param {Frame} frame */
  bind(frame) {
    const gl = this.gl;
    const p = this.progs;
    copyFlipped(gl, this.scene.giTarget, 3, this.mapDepth);
    const depth = this.mapDepth.textures[0];
    pass(gl, p.structure_slack, this.planes, { u_depth: depth });
    pass(gl, p.structure_coarse, this.fill.level0, { u_indirect: this.giMap.textures[1], u_depth: depth },
      { u_step: this.uniforms.u_step });
    const coarse = this.fill.run();
    pass(gl, p.structure_mean, this.mean, { u_sums: this.fill.level0.textures[1] });
    sync(gl, this.mean, 0);
    const vp = frame.gi.view_proj; // column-major: row 3 is elements 3, 7, 11, 15
    this.bound = { wRow: [vp[3], vp[7], vp[11], vp[15]], near: frame.gi.near, viewProj: vp, coarse };
  }

  // Per frame: the uv pass, then the warp (resample, depth test, fallback) into this.warped.
  /**
   * @param {Frame} frame
   * @param {Target} diTarget
   */
  warp(frame, diTarget) {
    const gl = this.gl;
    const bound = this.bound;
    if (!bound) throw new Error("GIGAN's pane warps with no map bound");
    const uv = this.scene.renderUV(frame, bound.viewProj);
    const { u_tol_hi, u_tol_lo, u_inv_step } = this.uniforms;
    pass(gl, this.progs.structure_warp, this.warped, {
      u_uv: uv.textures[0], u_position: uv.textures[1], u_code: uv.textures[2], u_di: diTarget.textures[0],
      u_planes: this.planes.textures[0], u_gi: this.giMap.textures[0], u_coarse: bound.coarse.textures[0],
      u_mean: this.mean.textures[0],
    }, { u_w_row: bound.wRow, u_near: bound.near, u_tol_hi, u_tol_lo, u_inv_step, u_base: true });
    sync(gl, this.warped, 0);
  }

  /**
   * @param {Target} diTarget
   * @param {number} tau
   */
  blend(diTarget, tau) {
    this.blender.draw(diTarget.textures[0], this.warped.textures[0], tau);
  }
}
