// Eq. 1, the last stage of both clients: the warped map and the frame's DI composed on linear radiance, then the
// project's tone map for the screen (gicore.blend, gicore.tonemap): shaders.json's compose, gicore.gl.blend's
// source with TONEMAP defined.

import { pass, programs, sync } from "./glutil.js";

export class Blend {
  /**
   * @param {import("./glutil.js").GL} gl
   * @param {import("./glutil.js").Shaders} shaders
   */
  constructor(gl, shaders) {
    this.gl = gl;
    this.prog = programs(gl, shaders, ["compose"]).compose;
  }

  /**
   * tau * DI + (1 - tau) * warped onto the canvas (eq. 1), each weight rounded to float32 by WebGL.
   * @param {WebGLTexture} diTexture
   * @param {WebGLTexture} warpedTexture
   * @param {number} tau
   */
  draw(diTexture, warpedTexture, tau) {
    const gl = this.gl;
    pass(gl, this.prog, null, { u_di: diTexture, u_warped: warpedTexture }, { u_tau: tau, u_one_minus_tau: 1 - tau });
    sync(gl, null);
  }
}
