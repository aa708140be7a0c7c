// GIGAN in the browser (paper III): DI + G-buffers at the GI camera -> the ONNX generator (onnxruntime-web)
// -> the structure-aware warp (Algorithm 1, eq. 5) and eq. 1's blend in shaders. The encoding is
// gigan_local.preprocess's, the warp gigan_local.warp's: depth test with slope slack, bilinear taps that drop
// out when they fail it, and the current DI plus the map's coarse indirect light where no tap passes.

import { FULLSCREEN_VERTEX, TONEMAP_GLSL, bindTarget, bindTextures, fullscreen, program, readFloats, setUniforms,
  sync, target, texture } from "./glutil.js";

const WARP_FRAGMENT = `#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D u_uv;      // GI-camera clip (x, y) of each pixel's point (the uv pass)
uniform highp sampler2D u_pos;     // world position
uniform highp sampler2D u_code;    // 0 background, 1 untextured surface, 2 textured
uniform highp sampler2D u_di;      // the current frame's DI (the fallback's base)
uniform highp sampler2D u_gi;      // the GI map, linear radiance (GL rows: row 0 at the bottom)
uniform highp sampler2D u_gidepth; // the GI camera's linear view depth (0: background)
uniform highp sampler2D u_coarse;  // the map's indirect light x hit, hit in alpha, with mipmaps
uniform vec4 u_w_row;              // clip w = u_w_row . (p, 1) under the GI camera
uniform float u_near;
uniform float u_tol;               // DEPTH_REL_TOL
uniform float u_coarse_lod;        // the mip level about FALLBACK_TEXELS texels across
layout(location = 0) out vec4 o_gi;

const float SUBTEXEL = 256.0;

float depth_at(ivec2 t) { return texelFetch(u_gidepth, t, 0).r; }

// gigan_local.warp.depth_slack: per axis the smaller depth step to a neighbour that is not background
float slack(ivec2 t, ivec2 size) {
  float d = depth_at(t);
  if (d <= 0.0) return 0.0;
  float s = 0.0;
  for (int axis = 0; axis < 2; ++axis) {
    ivec2 e = axis == 0 ? ivec2(1, 0) : ivec2(0, 1);
    ivec2 a = t - e, b = t + e;
    bool inside = a.x >= 0 && a.y >= 0 && b.x < size.x && b.y < size.y;
    if (!inside) continue;  // the frame's border: no step
    float da = depth_at(a), db = depth_at(b);
    float step = 1e30;
    if (da > 0.0) step = min(step, abs(d - da));
    if (db > 0.0) step = min(step, abs(db - d));
    if (step < 1e30) s += step;
  }
  return s;
}

vec3 coarse(vec2 xy, vec2 size) {  // bilinear lookup of the coarse level, hit-weighted
  vec4 c = textureLod(u_coarse, (xy + 0.5) / size, u_coarse_lod);
  if (c.a <= 0.0) c = textureLod(u_coarse, vec2(0.5), 20.0);  // no hit near: the map's mean
  return c.a > 0.0 ? c.rgb / c.a : vec3(0.0);
}

void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  float code = texelFetch(u_code, p, 0).r;
  vec3 di = texelFetch(u_di, p, 0).rgb;
  if (code < 0.5) { o_gi = vec4(0.0); return; }  // background
  vec4 mean = textureLod(u_coarse, vec2(0.5), 20.0);
  vec3 fallback_mean = di + (mean.a > 0.0 ? mean.rgb / mean.a : vec3(0.0));
  if (code < 1.5) { o_gi = vec4(fallback_mean, 0.0); return; }  // untextured (an area light)
  ivec2 size = textureSize(u_gi, 0);
  vec2 c = texelFetch(u_uv, p, 0).xy;
  vec3 pos = texelFetch(u_pos, p, 0).xyz;
  float w = dot(u_w_row.xyz, pos) + u_w_row.w;
  if (w <= u_near) { o_gi = vec4(fallback_mean, 0.0); return; }  // behind the GI camera
  float half_w = 0.5 / w;
  vec2 xy = (c * half_w + 0.5) * vec2(size) - 0.5;  // texel coordinates, centres at integers (GL rows)
  bool ok = all(greaterThanEqual(xy, vec2(-0.5))) && all(lessThanEqual(xy, vec2(size) - 0.5));
  xy = clamp(xy, vec2(0.0), vec2(size - 1));
  vec2 x0 = floor(xy);
  vec2 f = floor((xy - x0) * SUBTEXEL + 0.5) / SUBTEXEL;
  ivec2 a = ivec2(x0);
  ivec2 b = min(a + 1, size - 1);
  ivec2 taps[4] = ivec2[4](a, ivec2(b.x, a.y), ivec2(a.x, b.y), b);
  float weights[4] = float[4]((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
  vec3 sum = vec3(0.0);
  float total = 0.0;
  for (int i = 0; i < 4; ++i) {
    float d = depth_at(taps[i]);
    if (d <= 0.0) continue;
    float s = slack(taps[i], size);
    if (d - s <= w * (1.0 + u_tol) && d + s >= w * (1.0 - u_tol)) {
      sum += weights[i] * texelFetch(u_gi, taps[i], 0).rgb;
      total += weights[i];
    }
  }
  ok = ok && total > 0.0;
  o_gi = ok ? vec4(sum / total, 1.0) : vec4(di + coarse(xy, vec2(size)), 0.0);
}`;

// The map's indirect light max(GI - DI, 0) on surface texels, premultiplied by the hit mask (mipmapped after).
const COARSE_FRAGMENT = `#version 300 es
precision highp float;
uniform highp sampler2D u_gi;
uniform highp sampler2D u_gidi;
uniform highp sampler2D u_gidepth;
out vec4 o;
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  float hit = texelFetch(u_gidepth, p, 0).r > 0.0 ? 1.0 : 0.0;
  o = vec4(max(texelFetch(u_gi, p, 0).rgb - texelFetch(u_gidi, p, 0).rgb, 0.0) * hit, hit);
}`;

// Eq. 1 on linear radiance, then the project's tone map for the screen.
export const BLEND_FRAGMENT = `#version 300 es
precision highp float;
uniform highp sampler2D u_di;
uniform highp sampler2D u_warped;
uniform float u_tau;
out vec4 o;
${TONEMAP_GLSL}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec3 di = texelFetch(u_di, p, 0).rgb;
  vec3 gi = texelFetch(u_warped, p, 0).rgb;
  o = vec4(tonemap(u_tau * di + (1.0 - u_tau) * gi), 1.0);
}`;

const FALLBACK_TEXELS = 32;
const DEPTH_REL_TOL = 0.02;

export class GiganSystem {
  constructor(gl, scene, modelConfig, session, ort) {
    this.gl = gl;
    this.scene = scene;
    this.session = session;
    this.ort = ort;
    this.spec = modelConfig.input; // buffers, depth_scale
    const n = (this.n = modelConfig.resolution);
    if (n !== scene.n) throw new Error(`the model runs at ${n}² but the scene renders ${scene.n}²`);
    this.warpProg = program(gl, FULLSCREEN_VERTEX, WARP_FRAGMENT);
    this.coarseProg = program(gl, FULLSCREEN_VERTEX, COARSE_FRAGMENT);
    this.blendProg = program(gl, FULLSCREEN_VERTEX, BLEND_FRAGMENT);
    this.giTex = texture(gl, n, n, gl.RGBA32F);
    this.coarse = target(gl, n, n, [gl.RGBA16F], { depth: false, mips: [0] });
    this.warped = target(gl, n, n, [gl.RGBA32F], { depth: false });
    this.input = new Float32Array(this.spec.buffers.reduce((c, b) => c + { di: 3, albedo: 3, normal: 3, depth: 1, mask: 1 }[b], 0) * n * n);
    this.reads = [0, 1, 3, 4].map(() => new Float32Array(n * n * 4));
    this.radiance = new Float32Array(n * n * 4);
    this.bound = null;
  }

  // DI + G-buffers at the GI camera, read back (the generator runs on the CPU).
  renderInput(frame) {
    const gl = this.gl;
    const t = this.scene.renderGI(frame);
    const [albedo, normal, depth, di] = [0, 1, 3, 4].map((a, i) => readFloats(gl, t, a, this.reads[i]));
    return { albedo, normal, depth, di };
  }

  // gigan_local.preprocess.frame_to_input: NCHW float32 in [-1, 1], rows top-down (GL's are bottom-up).
  encode(buf) {
    const n = this.n;
    const plane = n * n;
    const out = this.input;
    const s = this.spec.depth_scale;
    let c = 0;
    for (const name of this.spec.buffers) {
      const src = buf[name === "mask" ? "depth" : name];
      const channels = { di: 3, albedo: 3, normal: 3, depth: 1, mask: 1 }[name];
      for (let row = 0; row < n; row++) {
        const srcRow = (n - 1 - row) * n;
        for (let col = 0; col < n; col++) {
          const i = (srcRow + col) * 4;
          const o = row * n + col;
          for (let k = 0; k < channels; k++) {
            const x = src[i + k];
            let v;
            if (name === "di") { const y = Math.max(x, 0); v = 2 * Math.pow(y / (1 + y), 1 / 2.2) - 1; }
            else if (name === "albedo") v = 2 * Math.min(Math.max(x, 0), 1) - 1;
            else if (name === "normal") v = x;
            else if (name === "depth") { const d = Math.max(x, 0); v = 2 * (d / (d + s)) - 1; }
            else v = src[i] > 0 ? 1 : -1;
            out[(c + k) * plane + o] = v;
          }
        }
      }
      c += channels;
    }
    return out;
  }

  // The generator's output (3xHxW in [-1, 1]) to linear radiance (gigan_local.preprocess.output_to_radiance),
  // uploaded with GL's rows; returns the tone-mapped display values HxWx3 (the parity check's quantity).
  decode(y) {
    const n = this.n;
    const plane = n * n;
    const display = new Float32Array(plane * 3);
    const rad = this.radiance;
    for (let row = 0; row < n; row++) {
      const glRow = n - 1 - row;
      for (let col = 0; col < n; col++) {
        const o = row * n + col;
        for (let k = 0; k < 3; k++) {
          const d = Math.min(Math.max((y[k * plane + o] + 1) * 0.5, 0), 1);
          display[o * 3 + k] = d;
          const g = Math.pow(Math.min(d, 1 - 1e-5), 2.2);
          rad[(glRow * n + col) * 4 + k] = g / (1 - g);
        }
        rad[(glRow * n + col) * 4 + 3] = 1;
      }
    }
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.giTex);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, n, n, gl.RGBA, gl.FLOAT, rad);
    return display;
  }

  async infer(tensor) {
    const n = this.n;
    const feeds = { [this.session.inputNames[0]]: new this.ort.Tensor("float32", tensor, [1, tensor.length / (n * n), n, n]) };
    const t0 = performance.now();
    const result = await this.session.run(feeds);
    const ms = performance.now() - t0;
    return { y: result[this.session.outputNames[0]].data, ms };
  }

  // One GI map: stages gi_render, inference (encoding, session.run, decoding and upload), and its bind.
  async produce(frame) {
    const t = {};
    let t0 = performance.now();
    const buffers = this.renderInput(frame);
    t.gi_render = performance.now() - t0;
    t0 = performance.now();
    const tensor = this.encode(buffers);
    const { y, ms } = await this.infer(tensor);
    const display = this.decode(y);
    sync(this.gl, this.scene.giTarget, 0);
    t.inference = performance.now() - t0;
    t.session_run = ms;
    t0 = performance.now();
    this.bind(frame);
    t.bind = performance.now() - t0;
    return { stages: t, buffers, display };
  }

  // Per map: the coarse fallback level (indirect light, mipmapped), and the GI camera's projection row.
  bind(frame) {
    const gl = this.gl;
    const gi = this.scene.giTarget;
    bindTarget(gl, this.coarse);
    gl.useProgram(this.coarseProg.p);
    bindTextures(gl, this.coarseProg, { u_gi: [4, this.giTex], u_gidi: [5, gi.textures[4]], u_gidepth: [6, gi.textures[3]] });
    fullscreen(gl);
    gl.bindTexture(gl.TEXTURE_2D, this.coarse.textures[0]);
    gl.generateMipmap(gl.TEXTURE_2D);
    sync(gl, this.coarse, 0);
    const vp = frame.gi.view_proj; // column-major: row 3 is elements 3, 7, 11, 15
    this.bound = { wRow: [vp[3], vp[7], vp[11], vp[15]], near: frame.gi.near, viewProj: vp };
  }

  // Per frame: the uv pass, then the warp (resample, depth test, fallback) into this.warped.
  warp(frame, diTarget) {
    const gl = this.gl;
    const uv = this.scene.renderUV(frame, this.bound.viewProj);
    bindTarget(gl, this.warped);
    gl.useProgram(this.warpProg.p);
    const gi = this.scene.giTarget;
    bindTextures(gl, this.warpProg, {
      u_uv: [4, uv.textures[0]], u_pos: [5, uv.textures[1]], u_code: [6, uv.textures[2]], u_di: [7, diTarget.textures[0]],
      u_gi: [8, this.giTex], u_gidepth: [9, gi.textures[3]], u_coarse: [10, this.coarse.textures[0]],
    });
    setUniforms(gl, this.warpProg, {
      u_w_row: this.bound.wRow, u_near: this.bound.near, u_tol: DEPTH_REL_TOL,
      u_coarse_lod: Math.log2(Math.ceil(this.n / FALLBACK_TEXELS)),
    });
    fullscreen(gl);
    sync(gl, this.warped, 0);
  }

  blend(diTarget, tau) {
    const gl = this.gl;
    bindTarget(gl, null);
    gl.useProgram(this.blendProg.p);
    bindTextures(gl, this.blendProg, { u_di: [4, diTarget.textures[0]], u_warped: [5, this.warped.textures[0]] });
    setUniforms(gl, this.blendProg, { u_tau: tau });
    fullscreen(gl);
    sync(gl, null);
  }
}
