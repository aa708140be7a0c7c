// Eq. 1, the last stage of both clients: the warped map and the frame's DI composed on linear radiance, then the
// project's tone map for the screen (gicore.blend, gicore.tonemap).

import { FULLSCREEN_VERTEX, TONEMAP_GLSL, bindTarget, bindTextures, fullscreen, program, setUniforms, sync }
  from "./glutil.js";

// Eq. 1 on linear radiance, then the project's tone map for the screen.
const BLEND_FRAGMENT = `#version 300 es
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

export class Blend {
  constructor(gl) {
    this.gl = gl;
    this.prog = program(gl, FULLSCREEN_VERTEX, BLEND_FRAGMENT);
  }

  // tau * DI + (1 - tau) * warped onto the canvas (eq. 1).
  draw(diTexture, warpedTexture, tau) {
    const gl = this.gl;
    bindTarget(gl, null);
    gl.useProgram(this.prog.p);
    bindTextures(gl, this.prog, { u_di: [4, diTexture], u_warped: [5, warpedTexture] });
    setUniforms(gl, this.prog, { u_tau: tau });
    fullscreen(gl);
    sync(gl, null);
  }
}
