// gicore.fill.push_pull in shaders (shaders.json's pull and push, gicore/gl/glsl's), as gicore.gl.fill.PushPull
// draws it on the desktop: the pixel-level warp fills its holes with it, the structure-aware warp's fallback level
// is made with it. Levels hold colour premultiplied by the weight, the weight in alpha; texel rows are image rows.

import { pass, target } from "./glutil.js";

/** @typedef {import("./glutil.js").Program} Program */
/** @typedef {import("./glutil.js").Target} Target */

/**
 * The push-pull's level sizes, finest first: halved (rounded up) until one pixel is left (gicore.gl.fill).
 * @param {number} w
 * @param {number} h
 */
function pyramidSizes(w, h) {
  const sizes = [[w, h]];
  let last = sizes[0];
  while (Math.max(...last) > 1) sizes.push((last = last.map((s) => Math.ceil(s / 2))));
  return sizes;
}

export class PushPull {
  /**
   * @param {import("./glutil.js").GL} gl
   * @param {{pull: Program, push: Program}} progs
   * @param {number} w
   * @param {number} h
   * @param {number} [extra] more float targets drawn with the finest level (a pass writing several outputs)
   */
  constructor(gl, progs, w, h, extra = 0) {
    this.gl = gl;
    this.progs = progs;
    const sizes = pyramidSizes(w, h);
    /** @param {number[][]} list */
    const levels = (list) => list.map(([sw, sh]) => target(gl, sw, sh, [gl.RGBA32F], { depth: false }));
    this.level0 = target(gl, w, h, Array(1 + extra).fill(gl.RGBA32F), { depth: false });
    this.pulled = [this.level0, ...levels(sizes.slice(1))];
    this.pushed = levels(sizes.slice(0, -1));
  }

  // The filled image, once the finest level is drawn into level0; with `mask`, a texture whose alpha says where
  // the frame sees a surface, the pixels off it are background (0, alpha 1).
  /**
   * @param {WebGLTexture | null} [mask]
   * @returns {Target}
   */
  run(mask = null) {
    const { gl, progs } = this;
    this.pulled.slice(1).forEach((level, i) => pass(gl, progs.pull, level, { u_finer: this.pulled[i].textures[0] }));
    const top = this.pushed.length - 1;
    for (let i = top; i >= 0; i--) {
      const coarser = (i === top ? this.pulled[this.pulled.length - 1] : this.pushed[i + 1]).textures[0];
      pass(gl, progs.push, this.pushed[i], { u_level: this.pulled[i].textures[0], u_coarser: coarser, u_mask: mask ?? coarser },
        { u_top: i === top, u_masked: i === 0 && mask !== null });
    }
    return this.pushed[0] ?? this.pulled[0];
  }
}
