// Cloud baking in the browser: POST /v1/gimap (same origin: gigan-web forwards it to the server or to the
// network-sim proxy) and decoding, both in a worker (map_worker.js), off the page's thread; pixel-level 3D warp
// in shaders (baseline_cloudbaking.warp: every texel with a depth unprojected, projected into the local camera
// and splatted as a square of its footprint, the nearest point winning; holes on surfaces filled by gicore.fill's
// push-pull pyramid), then eq. 1's blend. The splat, fill and blend shaders are the desktop GL warp's
// (baseline_cloudbaking.gl_warp), from shaders.json; they work in image rows, the page's frames have GL's.

import { bindTarget, bindTextures, copyFlipped, pass, programs, setUniforms, sync, target, texture } from "./glutil.js";
import { Blend } from "./blend.js";
import { PushPull } from "./fill.js";

/** @typedef {import("./glutil.js").Target} Target */
/** @typedef {import("./glutil.js").Texture} Texture */
/** @typedef {import("./scene.js").Frame} Frame */
/** @typedef {import("./payload.js").MapReply} MapReply */
/**
 * A map as it lands on the page: the worker's reply, its times on the page's clock.
 * @typedef {Omit<MapReply, "times"> & MapReply["times"]} Landed
 */
/**
 * A cloud map bound: its point cloud's points and colours (pixel_cloud), their count, the stored map's address.
 * @typedef {{points: WebGLTexture, colours: WebGLTexture, n: number, location: string | null}} BoundMap
 */

const PROGRAMS = /** @type {const} */ (["pixel_cloud", "pixel_splat", "pixel_resolve", "pull", "push"]);

/**
 * A 4x4 column-major inverse (cofactors).
 * @param {Float32Array} m
 */
function invert(m) {
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

/** @param {number[][]} rows */
const columnMajor = (rows) => new Float32Array([0, 1, 2, 3].flatMap((c) => rows.map((r) => r[c])));

// The maps fetched and decoded in a module worker (map_worker.js), so that a map's bytes need not wait for the
// page's thread, busy drawing, to be read and decoded. get(url, body) resolves with the worker's reply, its times
// on the page's clock; its errors reject, and once the worker itself fails every get rejects with that error.
class MapWorker {
  constructor() {
    this.worker = new Worker(new URL("./map_worker.js", import.meta.url), { type: "module" });
    /** @type {Map<number, {resolve: (landed: Landed) => void, reject: (error: Error) => void}>} */
    this.pending = new Map();
    this.next = 0;
    /** @type {Error | null} */
    this.failed = null;
    /** @param {MessageEvent<MapReply | {id: number, error: string}>} event */
    this.worker.onmessage = ({ data }) => {
      const p = this.pending.get(data.id);
      if (!p) return;
      this.pending.delete(data.id);
      if ("error" in data) p.reject(new Error(data.error));
      else p.resolve(onPageClock(data));
    };
    this.worker.onerror = (e) => this.fail(e.message || "map_worker.js did not load");
    this.worker.onmessageerror = () => this.fail("a reply could not be read");
  }

  /** @param {string} message */
  fail(message) {
    this.failed = new Error(`the cloud maps' worker: ${message}`);
    for (const p of this.pending.values()) p.reject(/** @type {Error} */ (this.failed));
    this.pending.clear();
  }

  /**
   * @param {string} url
   * @param {string} body
   * @returns {Promise<Landed>}
   */
  get(url, body) {
    if (this.failed) return Promise.reject(this.failed);
    const id = this.next++;
    return new Promise((resolve, reject) => {
      this.pending.set(id, { resolve, reject });
      this.worker.postMessage({ id, url: new URL(url, location.href).href, body });
    });
  }
}

/**
 * A reply's times (ms since the epoch) as performance.now() readings of the page.
 * @param {MapReply} reply
 * @returns {Landed}
 */
const onPageClock = ({ times, ...rest }) => {
  const page = /** @type {MapReply["times"]} */ (
    Object.fromEntries(Object.entries(times).map(([k, t]) => [k, t - performance.timeOrigin])));
  return { ...rest, ...page };
};

export class CloudSystem {
  /**
   * @param {import("./glutil.js").GL} gl
   * @param {import("./scene.js").SceneRenderer} scene
   * @param {{scene: string, resolution: number, codec: string, spp: number}} config the request's settings
   * @param {import("./glutil.js").Shaders} shaders
   */
  constructor(gl, scene, config, shaders) {
    this.gl = gl;
    this.scene = scene;
    this.config = config;
    const n = scene.n;
    this.progs = programs(gl, shaders, PROGRAMS);
    this.empty = shaders.pixel.empty; // the splat targets' clear value: no point
    // each byte's linear value (gicore.tonemap.LINEAR_OF_U8): the map's colours as the Python client decodes them
    this.linearOfU8 = texture(gl, 256, 1, gl.R32F);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 256, 1, gl.RED, gl.FLOAT, new Float32Array(shaders.pixel.linear_of_u8));
    this.blender = new Blend(gl, shaders);
    /** @param {number[]} formats */
    const float = (formats) => target(gl, n, n, formats, { depth: false });
    this.mask = float([gl.RGBA32F]); // the frame's DI, its surface mask in alpha, in image rows
    this.nearest = float([gl.R32F]);
    this.index = float([gl.R32F]);
    this.fill = new PushPull(gl, { pull: this.progs.pull, push: this.progs.push }, n, n);
    this.warped = float([gl.RGBA32F]); // GL rows, as the frame's DI
    /** @type {Target | null} the bound map's point cloud: points and colours (pixel_cloud), image rows */
    this.map = null;
    /** @type {BoundMap | null} */
    this.bound = null;
    this.worker = new MapWorker();
  }

  /** @param {Frame} frame */
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
  /**
   * @param {Frame} frame
   * @param {string} url
   */
  request(frame, url) {
    return this.worker.get(url, this.body(frame));
  }

  // A decoded map uploaded and bound (in the frame loop). Stages: transmission (request + transfer, from the
  // network stack's timestamps where it has them), server (its own timings), decode (from the last byte's
  // arrival until the map is uploaded: decoded in the worker, then the wait for the page's thread and its next
  // frame, and the upload: the page's own cost, as GIGAN's inference counts its wait), decode_work (the
  // worker's decoding alone, timed there), upload, bind. `decoding`: where the decoding ran and when (page clock).
  /** @param {Landed} done */
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
    const proj = header.proj;
    this.bind(gi, dt, invert(columnMajor(header.view)), [proj[0][0], proj[1][1]], done.location);
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

  // A map's point cloud and colours drawn from its uploaded textures (pixel_cloud: the GI camera's eye -> world
  // `invView`, its `focal` lengths), bound; the textures are deleted.
  /**
   * @param {Texture} gi
   * @param {Texture} depth
   * @param {Float32Array} invView
   * @param {number[]} focal
   * @param {string | null} location
   */
  bind(gi, depth, invView, focal, location) {
    const gl = this.gl;
    const { w, h } = gi;
    const map = this.map?.w === w && this.map.h === h ? this.map
      : (this.map = target(gl, w, h, [gl.RGBA32F, gl.RGBA32F], { depth: false }));
    const inputs = { u_depth: depth, u_gi: gi, u_linear_of_u8: this.linearOfU8 };
    pass(gl, this.progs.pixel_cloud, map, inputs, { u_inv_view: invView, u_focal: focal });
    sync(gl, map, 0);
    gl.deleteTexture(gi);
    gl.deleteTexture(depth);
    this.bound = { points: map.textures[0], colours: map.textures[1], n: w * h, location };
  }

  /**
   * Compile and run every per-frame pass once on a blank 1x1 map (SwiftShader compiles on first draw), untimed.
   * @param {Frame} frame
   * @param {Target} diTarget
   */
  warmUp(frame, diTarget) {
    const gl = this.gl;
    const identity = new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
    this.bind(texture(gl, 1, 1, gl.RGBA8), texture(gl, 1, 1, gl.R32F), identity, [1, 1], null);
    this.warp(frame, diTarget);
    this.blend(diTarget, 0);
    this.bound = null;
  }

  // Per frame (baseline_cloudbaking.gl_warp.GLPixelWarp.draw): the bound map splatted into the local camera, its
  // winners' colours where the frame sees a surface, holes filled by push-pull; into this.warped (GL rows).
  /**
   * @param {Frame} frame
   * @param {Target} diTarget
   */
  warp(frame, diTarget) {
    const gl = this.gl;
    const bound = this.bound;
    if (!bound) throw new Error("the cloud pane warps with no map bound");
    copyFlipped(gl, diTarget, 0, this.mask);
    this.splat(frame, bound);
    const mask = this.mask.textures[0];
    pass(gl, this.progs.pixel_resolve, this.fill.level0,
      { u_index: this.index.textures[0], u_colours: bound.colours, u_mask: mask });
    copyFlipped(gl, this.fill.run(mask), 0, this.warped);
    sync(gl, this.warped, 0);
  }

  // The nearest point's depth per pixel, then the smallest index among the points at that depth, each pass
  // MIN-blended into a target cleared to "no point".
  /**
   * @param {Frame} frame
   * @param {BoundMap} bound
   */
  splat(frame, bound) {
    const gl = this.gl;
    const n = this.scene.n;
    const prog = this.progs.pixel_splat;
    gl.disable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.enable(gl.BLEND);
    gl.blendEquation(gl.MIN);
    /** @type {[Target, Target, boolean][]} */
    const passes = [[this.nearest, this.index, false], [this.index, this.nearest, true]];
    for (const [tgt, other, index] of passes) {
      bindTarget(gl, tgt);
      gl.clearBufferfv(gl.COLOR, 0, new Float32Array(4).fill(this.empty));
      gl.useProgram(prog.p);
      bindTextures(gl, prog, { u_points: [4, bound.points], u_nearest: [5, other.textures[0]] });
      setUniforms(gl, prog, { u_vp: frame.local.view_proj, u_near: frame.local.near,
        u_focal_px: frame.local.proj[0] * n / 2, u_size: [n, n], u_index: index });
      gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, bound.n);
    }
    gl.blendEquation(gl.FUNC_ADD);
    gl.disable(gl.BLEND);
  }

  /**
   * @param {Target} diTarget
   * @param {number} tau
   */
  blend(diTarget, tau) {
    this.blender.draw(diTarget.textures[0], this.warped.textures[0], tau);
  }
}
