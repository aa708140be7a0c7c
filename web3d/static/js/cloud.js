// Cloud baking in the browser: POST /v1/gimap (same origin: gigan-web forwards it to the server or to the
// network-sim proxy) and decoding, both in a worker (map_worker.js), off the page's thread; pixel-level 3D warp
// in shaders (baseline_cloudbaking.warp: every texel with a depth unprojected, projected into the local camera
// and splatted as a z-tested square of its footprint; holes on surfaces filled by gicore.fill's push-pull pyramid
// over the splats that landed on a surface), then eq. 1's blend.

import { FULLSCREEN_VERTEX, TONEMAP_GLSL, bindTarget, bindTextures, fullscreen, program, setUniforms, sync, target,
  texture } from "./glutil.js";
import { Blend } from "./blend.js";

const SPLAT_VERTEX = `#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D u_depth;  // the GI camera's linear view depth, rows top-down (0: background)
uniform highp sampler2D u_gi;     // the 8-bit tone-mapped GI map, rows top-down
uniform mat4 u_inv_view;          // GI camera: eye -> world
uniform vec2 u_focal;             // GI camera: proj[0][0], proj[1][1]
uniform mat4 u_target_vp;         // local camera
uniform float u_target_focal_px;  // local camera: proj[0][0] * width / 2
uniform float u_near;
out vec3 v_gi;
${TONEMAP_GLSL}
void main() {
  ivec2 size = textureSize(u_depth, 0);
  ivec2 t = ivec2(gl_VertexID % size.x, gl_VertexID / size.x);
  float d = texelFetch(u_depth, t, 0).r;
  vec2 ndc = vec2(2.0 * (float(t.x) + 0.5) / float(size.x) - 1.0, 1.0 - 2.0 * (float(t.y) + 0.5) / float(size.y));
  vec4 world = u_inv_view * vec4(ndc.x * d / u_focal.x, ndc.y * d / u_focal.y, -d, 1.0);
  vec4 clip = u_target_vp * world;
  if (d <= 0.0 || clip.w <= u_near) { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); gl_PointSize = 1.0; return; }
  // footprint: target pixels per source pixel at this point, rounded up (float noise must not make 1 into 2)
  float scale = d / (u_focal.x * float(size.x) * 0.5) * u_target_focal_px / clip.w;
  gl_PointSize = max(ceil(scale - 1e-3), 1.0);
  gl_Position = clip;
  v_gi = inverse_tonemap(min(texelFetch(u_gi, t, 0).rgb, vec3(254.5 / 255.0)));
}`;

const SPLAT_FRAGMENT = `#version 300 es
precision highp float;
in vec3 v_gi;
out vec4 o;
void main() { o = vec4(v_gi, 1.0); }`;

// gicore.fill.push_pull, one pass per pyramid level. Texel (x, y) of a level in the image's row order (row 0 at
// the top, as numpy's) is GL texel (x, h - 1 - y): the 2x2 blocks and the zero-weight padding of odd sizes fall
// where push_pull's do. Levels hold colour premultiplied by the weight, the weight in alpha.
const PYRAMID_GLSL = `
ivec2 flip(ivec2 t, ivec2 size) { return ivec2(t.x, size.y - 1 - t.y); }  // image rows <-> GL rows
`;

// Pull: a level from the finer one, weight-normalised 2x2 sums with the weight clipped to 1. From the splat
// (u_first), the weight is 1 where a point landed on a surface of the local view, else 0.
const PULL_FRAGMENT = `#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D u_fine;
uniform highp sampler2D u_di;  // u_first: the local surface mask in alpha
uniform bool u_first;
out vec4 o;
${PYRAMID_GLSL}
vec4 fine(ivec2 t, ivec2 size) {
  if (t.x >= size.x || t.y >= size.y) return vec4(0.0);  // padding
  ivec2 g = flip(t, size);
  vec4 c = texelFetch(u_fine, g, 0);
  if (!u_first) return c;
  float w = c.a > 0.0 && texelFetch(u_di, g, 0).a > 0.0 ? 1.0 : 0.0;
  return vec4(c.rgb * w, w);
}
void main() {
  ivec2 size = textureSize(u_fine, 0);
  ivec2 t = 2 * flip(ivec2(gl_FragCoord.xy), (size + 1) / 2);
  vec4 s = fine(t, size) + fine(t + ivec2(1, 0), size) + fine(t + ivec2(0, 1), size) + fine(t + ivec2(1, 1), size);
  float w = min(s.a, 1.0);
  o = vec4(s.rgb * (w / max(s.a, 1e-12)), w);
}`;

// Push, coarse to fine: a level's own premultiplied colour plus (1 - weight) x its coarser parent (pixels
// repeated 2x2, as push_pull's); the coarsest level (u_top) is its colour over its weight.
const PUSH_FRAGMENT = `#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D u_pull;
uniform highp sampler2D u_coarser;
uniform bool u_top;
out vec4 o;
${PYRAMID_GLSL}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  vec4 c = texelFetch(u_pull, p, 0);
  if (u_top) { o = vec4(c.rgb / max(c.a, 1e-12), 1.0); return; }
  ivec2 parent = flip(flip(p, textureSize(u_pull, 0)) / 2, textureSize(u_coarser, 0));
  o = vec4(c.rgb + (1.0 - c.a) * texelFetch(u_coarser, parent, 0).rgb, 1.0);
}`;

// The finest level: the splat where a point landed on a surface (alpha 1), its pushed parent elsewhere on
// surfaces (alpha 0), 0 off them.
const FILL_FRAGMENT = `#version 300 es
precision highp float;
precision highp int;
uniform highp sampler2D u_splat;
uniform highp sampler2D u_di;   // alpha: the local surface mask
uniform highp sampler2D u_coarser;
out vec4 o;
${PYRAMID_GLSL}
void main() {
  ivec2 p = ivec2(gl_FragCoord.xy);
  if (texelFetch(u_di, p, 0).a <= 0.0) { o = vec4(0.0); return; }
  vec4 s = texelFetch(u_splat, p, 0);
  if (s.a > 0.0) { o = vec4(s.rgb, 1.0); return; }
  ivec2 parent = flip(flip(p, textureSize(u_splat, 0)) / 2, textureSize(u_coarser, 0));
  o = vec4(texelFetch(u_coarser, parent, 0).rgb, 0.0);
}`;

function invert(m) {
  // a 4x4 column-major inverse (cofactors)
  const inv = new Float32Array(16);
  const [a00, a01, a02, a03, a10, a11, a12, a13, a20, a21, a22, a23, a30, a31, a32, a33] = m;
  const b00 = a00 * a11 - a01 * a10, b01 = a00 * a12 - a02 * a10, b02 = a00 * a13 - a03 * a10;
  const b03 = a01 * a12 - a02 * a11, b04 = a01 * a13 - a03 * a11, b05 = a02 * a13 - a03 * a12;
  const b06 = a20 * a31 - a21 * a30, b07 = a20 * a32 - a22 * a30, b08 = a20 * a33 - a23 * a30;
  const b09 = a21 * a32 - a22 * a31, b10 = a21 * a33 - a23 * a31, b11 = a22 * a33 - a23 * a32;
  const det = 1 / (b00 * b11 - b01 * b10 + b02 * b09 + b03 * b08 - b04 * b07 + b05 * b06);
  inv[0] = (a11 * b11 - a12 * b10 + a13 * b09) * det; inv[1] = (a02 * b10 - a01 * b11 - a03 * b09) * det;
  inv[2] = (a31 * b05 - a32 * b04 + a33 * b03) * det; inv[3] = (a22 * b04 - a21 * b05 - a23 * b03) * det;
  inv[4] = (a12 * b08 - a10 * b11 - a13 * b07) * det; inv[5] = (a00 * b11 - a02 * b08 + a03 * b07) * det;
  inv[6] = (a32 * b02 - a30 * b05 - a33 * b01) * det; inv[7] = (a20 * b05 - a22 * b02 + a23 * b01) * det;
  inv[8] = (a10 * b10 - a11 * b08 + a13 * b06) * det; inv[9] = (a01 * b08 - a00 * b10 - a03 * b06) * det;
  inv[10] = (a30 * b04 - a31 * b02 + a33 * b00) * det; inv[11] = (a21 * b02 - a20 * b04 - a23 * b00) * det;
  inv[12] = (a11 * b07 - a10 * b09 - a12 * b06) * det; inv[13] = (a00 * b09 - a01 * b07 + a02 * b06) * det;
  inv[14] = (a31 * b01 - a30 * b03 - a32 * b00) * det; inv[15] = (a20 * b03 - a21 * b01 + a22 * b00) * det;
  return inv;
}

const columnMajor = (rows) => new Float32Array([0, 1, 2, 3].flatMap((c) => rows.map((r) => r[c])));

// The maps fetched and decoded in a module worker (map_worker.js), so that a map's bytes need not wait for the
// page's thread, busy drawing, to be read and decoded. get(url, body) resolves with the worker's reply, its times
// on the page's clock; its errors reject, and once the worker itself fails every get rejects with that error.
class MapWorker {
  constructor() {
    this.worker = new Worker(new URL("./map_worker.js", import.meta.url), { type: "module" });
    this.pending = new Map(); // id -> {resolve, reject}
    this.next = 0;
    this.failed = null;
    this.worker.onmessage = ({ data }) => {
      const p = this.pending.get(data.id);
      this.pending.delete(data.id);
      if (data.error) p.reject(new Error(data.error));
      else p.resolve(onPageClock(data));
    };
    this.worker.onerror = (e) => this.fail(e.message || "map_worker.js did not load");
    this.worker.onmessageerror = () => this.fail("a reply could not be read");
  }

  fail(message) {
    this.failed = new Error(`the cloud maps' worker: ${message}`);
    for (const p of this.pending.values()) p.reject(this.failed);
    this.pending.clear();
  }

  get(url, body) {
    if (this.failed) return Promise.reject(this.failed);
    const id = this.next++;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject });
      this.worker.postMessage({ id, url: new URL(url, location.href).href, body });
    });
  }
}

// A reply's times (ms since the epoch) as performance.now() readings of the page.
const onPageClock = ({ times, ...rest }) =>
  ({ ...rest, ...Object.fromEntries(Object.entries(times).map(([k, t]) => [k, t - performance.timeOrigin])) });

export class CloudSystem {
  constructor(gl, scene, config) {
    this.gl = gl;
    this.scene = scene;
    this.config = config;
    const n = scene.n;
    this.splatProg = program(gl, SPLAT_VERTEX, SPLAT_FRAGMENT);
    this.pullProg = program(gl, FULLSCREEN_VERTEX, PULL_FRAGMENT);
    this.pushProg = program(gl, FULLSCREEN_VERTEX, PUSH_FRAGMENT);
    this.fillProg = program(gl, FULLSCREEN_VERTEX, FILL_FRAGMENT);
    this.blender = new Blend(gl);
    this.splat = target(gl, n, n, [gl.RGBA16F]);
    this.warped = target(gl, n, n, [gl.RGBA32F], { depth: false });
    // push-pull levels 1.. (each half the last, rounded up, down to 1x1): the pull's and the push's
    this.pulled = [];
    this.pushed = [];
    for (let size = Math.ceil(n / 2); this.pulled.at(-1)?.w !== 1; size = Math.ceil(size / 2)) {
      this.pulled.push(target(gl, size, size, [gl.RGBA32F], { depth: false }));
      this.pushed.push(target(gl, size, size, [gl.RGBA32F], { depth: false }));
    }
    this.bound = null;
    this.worker = new MapWorker();
  }

  body(frame) {
    const c = this.config;
    return JSON.stringify({
      scene: c.scene,
      camera: { eye: frame.gi.eye, target: frame.gi.target, up: frame.gi.up, fov: frame.gi.fov },
      light: frame.light, resolution: c.resolution, codec: c.codec, spp: c.spp,
    });
  }

  // The map at the frame's GI camera from `url` (/v1/gimap?profile=&store=), fetched and decoded (image, depth)
  // in the worker; resolves to what join() uploads and binds.
  request(frame, url) {
    return this.worker.get(url, this.body(frame));
  }

  // A decoded map uploaded and bound (in the frame loop). Stages: transmission (request + transfer, from the
  // network stack's timestamps where it has them), server (its own timings), decode (from the last byte's
  // arrival until the map is uploaded: decoded in the worker, then the wait for the page's thread and its next
  // frame, and the upload: the page's own cost, as GIGAN's inference counts its wait), decode_work (the
  // worker's decoding alone, timed there), upload, bind. `decoding`: where the decoding ran and when (page clock).
  join(done) {
    const gl = this.gl;
    const { header, h, w } = done;
    const t0 = performance.now();
    const gi = texture(gl, w, h, gl.RGBA8);
    gl.bindTexture(gl.TEXTURE_2D, gi);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, gl.RGBA, gl.UNSIGNED_BYTE, done.bitmap);
    const dt = texture(gl, w, h, gl.R32F);
    gl.bindTexture(gl.TEXTURE_2D, dt);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, w, h, gl.RED, gl.FLOAT, done.depth);
    sync(gl, null);
    done.bitmap.close();
    const upload = performance.now() - t0;
    const decode = performance.now() - done.arrived;
    const t1 = performance.now();
    if (this.bound) for (const t of [this.bound.gi, this.bound.depth]) gl.deleteTexture(t);
    const view = columnMajor(header.view);
    const proj = header.proj;
    this.bound = { gi, depth: dt, invView: invert(view), focal: [proj[0][0], proj[1][1]], near: header.camera.near, n: w * h,
      location: done.location };
    const bind = performance.now() - t1;
    const server = header.timings_ms || {};
    const total = server.total ?? 0;
    const request = done.firstByte - done.started - total;
    const transfer = done.arrived - done.firstByte;
    return {
      hit: header.hit, bytes: done.bytes, timing: done.timing,
      decoding: { in: done.scope, from: done.from, to: done.to },
      stages: { transmission: request + transfer, request, transfer, server: total, decode,
        decode_work: done.to - done.from, upload, bind, ...Object.fromEntries(
        Object.entries(server).filter(([k]) => k !== "total").map(([k, v]) => [`server_${k}`, v])) },
    };
  }

  // Compile and run every per-frame pass once on a blank 1x1 map (SwiftShader compiles on first draw), untimed.
  warmUp(frame, diTarget) {
    const gl = this.gl;
    const gi = texture(gl, 1, 1, gl.RGBA8);
    const depth = texture(gl, 1, 1, gl.R32F);
    const identity = new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
    this.bound = { gi, depth, invView: identity, focal: [1, 1], near: frame.local.near, n: 1 };
    this.warp(frame, diTarget);
    this.blend(diTarget, 0);
    gl.deleteTexture(gi);
    gl.deleteTexture(depth);
    this.bound = null;
  }

  // Per frame: splat the bound map into the local camera, fill holes on surfaces (push-pull).
  warp(frame, diTarget) {
    const gl = this.gl;
    const b = this.bound;
    bindTarget(gl, this.splat);
    gl.clearColor(0, 0, 0, 0);
    gl.clearDepth(1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
    gl.disable(gl.CULL_FACE);
    gl.useProgram(this.splatProg.p);
    bindTextures(gl, this.splatProg, { u_depth: [4, b.depth], u_gi: [5, b.gi] });
    setUniforms(gl, this.splatProg, {
      u_inv_view: b.invView, u_focal: b.focal, u_target_vp: frame.local.view_proj,
      u_target_focal_px: frame.local.proj[0] * this.scene.n / 2, u_near: frame.local.near,
    });
    gl.drawArrays(gl.POINTS, 0, b.n);
    this.pushPull(diTarget);
    sync(gl, this.warped, 0);
  }

  // gicore.fill.push_pull of the splat over the local surface mask, into this.warped.
  pushPull(diTarget) {
    const gl = this.gl;
    const pass = (prog, tgt, textures, uniforms) => {
      bindTarget(gl, tgt);
      gl.useProgram(prog.p);
      bindTextures(gl, prog, textures);
      setUniforms(gl, prog, uniforms);
      fullscreen(gl);
    };
    const di = [5, diTarget.textures[0]];
    this.pulled.forEach((level, i) => {
      const fine = i === 0 ? this.splat : this.pulled[i - 1];
      pass(this.pullProg, level, { u_fine: [4, fine.textures[0]], u_di: di }, { u_first: i === 0 });
    });
    for (let i = this.pushed.length - 1; i >= 0; i--) {
      const coarser = this.pushed[i + 1] ?? this.pulled[i]; // the top reads no parent (any texture not drawn to)
      pass(this.pushProg, this.pushed[i], { u_pull: [4, this.pulled[i].textures[0]], u_coarser: [6, coarser.textures[0]] },
        { u_top: i === this.pushed.length - 1 });
    }
    pass(this.fillProg, this.warped,
      { u_splat: [4, this.splat.textures[0]], u_di: di, u_coarser: [6, this.pushed[0].textures[0]] }, {});
  }

  blend(diTarget, tau) {
    this.blender.draw(diTarget.textures[0], this.warped.textures[0], tau);
  }
}
