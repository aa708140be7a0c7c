// GIGAN in the browser (paper III): DI + G-buffers at the GI camera -> the ONNX generator (onnxruntime-web)
// -> the structure-aware warp (Algorithm 1, eq. 5) and eq. 1's blend in shaders. The encoding is
// gigan_local.preprocess's, the warp gigan_local.warp's: depth test with slope slack, bilinear taps that drop
// out when they fail it, and the current DI plus the map's coarse indirect light where no tap passes.

import { FULLSCREEN_VERTEX, TONEMAP_GLSL, bindTarget, bindTextures, fullscreen, program, readFloats, setUniforms,
  sync, target, texture } from "./glutil.js";
import { Blend } from "./blend.js";

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

const CHANNELS = { di: 3, albedo: 3, normal: 3, depth: 1, mask: 1 };

// The encoding of each input buffer (gigan_local.preprocess), as a vec3 expression at pixel p.
const ENCODE = {
  di: "2.0 * tonemap(texelFetch(u_di, p, 0).rgb) - 1.0",
  albedo: "2.0 * clamp(texelFetch(u_albedo, p, 0).rgb, 0.0, 1.0) - 1.0",
  normal: "texelFetch(u_normal, p, 0).rgb",
  depth: "vec3(2.0 * (d / (d + u_depth_scale)) - 1.0)",
  mask: "vec3(d > 0.0 ? 1.0 : -1.0)",
};

// A fragment shader writing the network input's channels (buffer, component) four per target.
function encodeFragment(channels) {
  const targets = Math.ceil(channels.length / 4);
  const value = ([b, k]) => `(${ENCODE[b]})[${k}]`;
  const outs = [...Array(targets).keys()].map((a) => `layout(location = ${a}) out vec4 o${a};`).join("\n");
  const writes = [...Array(targets).keys()].map((a) => {
    const c = [0, 1, 2, 3].map((k) => (channels[4 * a + k] ? value(channels[4 * a + k]) : "0.0"));
    return `  o${a} = vec4(${c.join(", ")});`;
  }).join("\n");
  return `#version 300 es
precision highp float;
uniform highp sampler2D u_di;
uniform highp sampler2D u_albedo;
uniform highp sampler2D u_normal;
uniform highp sampler2D u_depth;
uniform float u_depth_scale;
${outs}
${TONEMAP_GLSL}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  float d = max(texelFetch(u_depth, p, 0).r, 0.0);
${writes}
}`;
}

// The generator's output planes (stacked, rows top-down) to linear radiance with GL's rows.
const DECODE_FRAGMENT = `#version 300 es
precision highp float;
uniform highp sampler2D u_y;
out vec4 o;
${TONEMAP_GLSL}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  int n = textureSize(u_y, 0).x;
  int row = n - 1 - p.y;
  vec3 y = vec3(texelFetch(u_y, ivec2(p.x, row), 0).r, texelFetch(u_y, ivec2(p.x, n + row), 0).r,
                texelFetch(u_y, ivec2(p.x, 2 * n + row), 0).r);
  o = vec4(inverse_tonemap(clamp((y + 1.0) * 0.5, 0.0, 1.0)), 1.0);
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
    this.blender = new Blend(gl);
    this.giMap = target(gl, n, n, [gl.RGBA32F], { depth: false });
    this.giTex = this.giMap.textures[0];
    this.output = texture(gl, n, 3 * n, gl.R32F); // the generator's output planes, stacked
    this.decodeProg = program(gl, FULLSCREEN_VERTEX, DECODE_FRAGMENT);
    const channels = this.spec.buffers.flatMap((b) => [...Array(CHANNELS[b]).keys()].map((k) => [b, k]));
    this.encodeProg = program(gl, FULLSCREEN_VERTEX, encodeFragment(channels));
    this.encoded = target(gl, n, n, Array(Math.ceil(channels.length / 4)).fill(gl.RGBA32F), { depth: false });
    this.encodedReads = this.encoded.textures.map(() => new Float32Array(n * n * 4));
    this.coarse = target(gl, n, n, [gl.RGBA16F], { depth: false, mips: [0] });
    this.warped = target(gl, n, n, [gl.RGBA32F], { depth: false });
    // the bound map's GI-camera depth: the G-buffer target is rendered anew by the next request while this map
    // is still warped
    this.mapDepth = target(gl, n, n, [gl.R32F], { depth: false });
    this.channels = channels.length;
    this.bound = null;
  }

  // The frame's GI-camera buffers read back as they are (rows bottom-up, RGBA): the parity check's input.
  readBuffers() {
    const t = this.scene.giTarget;
    return Object.fromEntries([["albedo", 0], ["normal", 1], ["depth", 3], ["di", 4]].map(([k, a]) => [k, readFloats(this.gl, t, a)]));
  }

  // gigan_local.preprocess.frame_to_input on the GPU (the encoding shader, 4 channels per target), read back and
  // reordered to NCHW with rows top-down (GL's are bottom-up), into a new array (the inference takes it over).
  encode() {
    const gl = this.gl;
    const gi = this.scene.giTarget;
    bindTarget(gl, this.encoded);
    gl.useProgram(this.encodeProg.p);
    bindTextures(gl, this.encodeProg, {
      u_albedo: [4, gi.textures[0]], u_normal: [5, gi.textures[1]], u_depth: [6, gi.textures[3]], u_di: [7, gi.textures[4]],
    });
    setUniforms(gl, this.encodeProg, { u_depth_scale: this.spec.depth_scale });
    fullscreen(gl);
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

  // The generator's output (3xHxW in [-1, 1]) to linear radiance (gigan_local.preprocess.output_to_radiance) in
  // a shader, into the GI map's texture (GL rows).
  decode(y) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.output);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, this.n, 3 * this.n, gl.RED, gl.FLOAT, y);
    bindTarget(gl, this.giMap);
    gl.useProgram(this.decodeProg.p);
    bindTextures(gl, this.decodeProg, { u_y: [4, this.output] });
    fullscreen(gl);
  }

  // The tone-mapped display values HxWx3 of an output (gigan_local.preprocess.output_to_display).
  display(y) {
    const plane = this.n * this.n;
    const out = new Float32Array(plane * 3);
    for (let o = 0; o < plane; o++) {
      for (let k = 0; k < 3; k++) out[o * 3 + k] = Math.min(Math.max((y[k * plane + o] + 1) * 0.5, 0), 1);
    }
    return out;
  }

  // session.run on a tensor (its buffer moves to onnxruntime-web's proxy worker: the caller keeps no view of it).
  async infer(tensor) {
    const n = this.n;
    const feeds = { [this.session.inputNames[0]]: new this.ort.Tensor("float32", tensor, [1, tensor.length / (n * n), n, n]) };
    const t0 = performance.now();
    const result = await this.session.run(feeds);
    const ms = performance.now() - t0;
    return { y: result[this.session.outputNames[0]].data, ms };
  }

  // A map's first half, at request time: DI + G-buffers at the GI camera, encoded and read back, and session.run
  // started (it runs in the worker). With `keep`, also the raw buffers and the input (the parity check's).
  request(frame, keep = false) {
    const stages = {};
    let t0 = performance.now();
    sync(this.gl, this.scene.renderGI(frame), 0);
    stages.gi_render = performance.now() - t0;
    t0 = performance.now();
    const tensor = this.encode();
    stages.encode = performance.now() - t0;
    const kept = keep ? { buffers: this.readBuffers(), input: tensor.slice() } : null;
    return { frame, stages, kept, run: this.infer(tensor), posted: performance.now() };
  }

  // Its second half, once session.run is done: the output decoded into the GI map and bound to the request's GI
  // camera. Stages: inference (encoding, the run as the page waited for it, decoding), session_run, bind.
  join(request, { y, ms }) {
    const waited = performance.now() - request.posted;
    const t0 = performance.now();
    this.decode(y);
    sync(this.gl, this.giMap, 0);
    const decode = performance.now() - t0;
    const t1 = performance.now();
    this.bind(request.frame);
    const bind = performance.now() - t1;
    if (request.kept) request.kept.display = this.display(y);
    const s = request.stages;
    return { gi_render: s.gi_render, inference: s.encode + waited + decode, session_run: ms, bind };
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
    gl.bindFramebuffer(gl.READ_FRAMEBUFFER, gi.fbo);
    gl.readBuffer(gl.COLOR_ATTACHMENT0 + 3);
    gl.bindFramebuffer(gl.DRAW_FRAMEBUFFER, this.mapDepth.fbo);
    gl.blitFramebuffer(0, 0, this.n, this.n, 0, 0, this.n, this.n, gl.COLOR_BUFFER_BIT, gl.NEAREST);
    const vp = frame.gi.view_proj; // column-major: row 3 is elements 3, 7, 11, 15
    this.bound = { wRow: [vp[3], vp[7], vp[11], vp[15]], near: frame.gi.near, viewProj: vp };
  }

  // Per frame: the uv pass, then the warp (resample, depth test, fallback) into this.warped.
  warp(frame, diTarget) {
    const gl = this.gl;
    const uv = this.scene.renderUV(frame, this.bound.viewProj);
    bindTarget(gl, this.warped);
    gl.useProgram(this.warpProg.p);
    bindTextures(gl, this.warpProg, {
      u_uv: [4, uv.textures[0]], u_pos: [5, uv.textures[1]], u_code: [6, uv.textures[2]], u_di: [7, diTarget.textures[0]],
      u_gi: [8, this.giTex], u_gidepth: [9, this.mapDepth.textures[0]], u_coarse: [10, this.coarse.textures[0]],
    });
    setUniforms(gl, this.warpProg, {
      u_w_row: this.bound.wRow, u_near: this.bound.near, u_tol: DEPTH_REL_TOL,
      u_coarse_lod: Math.log2(Math.ceil(this.n / FALLBACK_TEXELS)),
    });
    fullscreen(gl);
    sync(gl, this.warped, 0);
  }

  blend(diTarget, tau) {
    this.blender.draw(diTarget.textures[0], this.warped.textures[0], tau);
  }
}
