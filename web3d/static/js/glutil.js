// WebGL2 plumbing shared by both systems: programs (their sources come from web3d.export: scene.json's and
// shaders.json's), float render targets, a full-screen pass, sync.

/** @typedef {WebGL2RenderingContext} GL */
/**
 * A texture with its size, formats and mip levels.
 * @typedef {WebGLTexture & {w: number, h: number, internal: number, format: number, type: number,
 *   levels: number}} Texture
 */
/** @typedef {{fbo: WebGLFramebuffer, textures: Texture[], w: number, h: number}} Target */
/** @typedef {{loc: WebGLUniformLocation | null, size: number, type: number}} Uniform */
/** @typedef {{p: WebGLProgram, uniforms: Record<string, Uniform>}} Program */
/** @typedef {{vertex: string, fragment: string}} ProgramSource */
/** @typedef {number | boolean | number[] | Float32Array} UniformValue */
/**
 * shaders.json (web3d.shaders.page_shaders): the programs' sources and the constants Python owns.
 * @typedef {object} Shaders
 * @property {Record<string, ProgramSource>} programs
 * @property {{empty: number, linear_of_u8: number[]}} pixel the splat's "no point"; each byte's linear value
 * @property {Record<"u_step" | "u_tol_hi" | "u_tol_lo" | "u_inv_step", number>} structure the warp's constants
 * @property {{channels: number, targets: number}} encode the model input's channels and the encoding's targets
 */

export const ATTRIBS = ["in_pos", "in_nrm", "in_mat", "in_uv"];

/** @param {HTMLCanvasElement} canvas */
export function context(canvas) {
  const gl = canvas.getContext("webgl2", { antialias: false, depth: false, preserveDrawingBuffer: true });
  if (!gl) throw new Error("this browser has no WebGL2");
  // float colour attachments (G-buffers, GI maps) and their readback need this extension
  if (!gl.getExtension("EXT_color_buffer_float")) throw new Error("WebGL2 lacks EXT_color_buffer_float");
  // the pixel-level warp's splat keeps the nearest point with MIN blending on float32 targets
  if (!gl.getExtension("EXT_float_blend")) throw new Error("WebGL2 lacks EXT_float_blend");
  return gl;
}

/**
 * @param {GL} gl
 * @param {string} vertex
 * @param {string} fragment
 * @returns {Program}
 */
export function program(gl, vertex, fragment) {
  const p = gl.createProgram();
  /** @type {[number, string][]} */
  const stages = [[gl.VERTEX_SHADER, vertex], [gl.FRAGMENT_SHADER, fragment]];
  for (const [type, src] of stages) {
    const s = /** @type {WebGLShader} */ (gl.createShader(type));
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
    gl.attachShader(p, s);
  }
  ATTRIBS.forEach((name, i) => gl.bindAttribLocation(p, i, name));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`link: ${gl.getProgramInfoLog(p)}`);
  // uniform locations and array sizes, so that arrays longer than what the compiler kept can be cut
  /** @type {Record<string, Uniform>} */
  const uniforms = {};
  const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const info = /** @type {WebGLActiveInfo} */ (gl.getActiveUniform(p, i));
    const name = info.name.replace(/\[0\]$/, "");
    uniforms[name] = { loc: gl.getUniformLocation(p, info.name), size: info.size, type: info.type };
  }
  return { p, uniforms };
}

/**
 * Set uniforms by name; names the program does not use (compiled out) are skipped.
 * @param {GL} gl
 * @param {Program} prog
 * @param {Record<string, UniformValue>} values
 */
export function setUniforms(gl, prog, values) {
  for (const [name, value] of Object.entries(values)) {
    const u = prog.uniforms[name];
    if (!u) continue;
    const t = u.type;
    if (typeof value === "number" || typeof value === "boolean") {
      if (t === gl.FLOAT) gl.uniform1f(u.loc, Number(value));
      else gl.uniform1i(u.loc, Number(value)); // int, bool, samplers
    } else if (t === gl.FLOAT_MAT4) gl.uniformMatrix4fv(u.loc, false, value.slice(0, 16 * u.size));
    else if (t === gl.FLOAT_VEC4) gl.uniform4fv(u.loc, value.slice(0, 4 * u.size));
    else if (t === gl.FLOAT_VEC3) gl.uniform3fv(u.loc, value);
    else if (t === gl.FLOAT_VEC2) gl.uniform2fv(u.loc, value);
    else gl.uniform1fv(u.loc, value.slice(0, u.size)); // a float array
  }
}

/**
 * @param {GL} gl
 * @param {number} w
 * @param {number} h
 * @param {number} internal
 * @param {{filter?: number, mips?: boolean}} [options]
 * @returns {Texture}
 */
export function texture(gl, w, h, internal, { filter = gl.NEAREST, mips = false } = {}) {
  /** @type {Record<number, [number, number]>} */
  const formats = {
    [gl.RGBA32F]: [gl.RGBA, gl.FLOAT],
    [gl.RGBA16F]: [gl.RGBA, gl.HALF_FLOAT],
    [gl.RG32F]: [gl.RG, gl.FLOAT],
    [gl.R32F]: [gl.RED, gl.FLOAT],
    [gl.RGBA8]: [gl.RGBA, gl.UNSIGNED_BYTE],
    [gl.DEPTH_COMPONENT32F]: [gl.DEPTH_COMPONENT, gl.FLOAT],
  };
  const [format, type] = formats[internal];
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  const levels = mips ? Math.floor(Math.log2(Math.max(w, h))) + 1 : 1;
  gl.texStorage2D(gl.TEXTURE_2D, levels, internal, w, h);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, mips ? gl.LINEAR_MIPMAP_NEAREST : filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  return Object.assign(t, { w, h, internal, format, type, levels });
}

/**
 * A framebuffer over colour textures (attachment i = textures[i]) with a depth buffer when asked.
 * @param {GL} gl
 * @param {number} w
 * @param {number} h
 * @param {number[]} internals
 * @param {{depth?: boolean, mips?: number[]}} [options]
 * @returns {Target}
 */
export function target(gl, w, h, internals, { depth = true, mips = [] } = {}) {
  const fbo = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
  const textures = internals.map((f, i) => {
    const t = texture(gl, w, h, f, { mips: mips.includes(i), filter: mips.includes(i) ? gl.LINEAR : gl.NEAREST });
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0 + i, gl.TEXTURE_2D, t, 0);
    return t;
  });
  if (depth) {
    const rb = gl.createRenderbuffer();
    gl.bindRenderbuffer(gl.RENDERBUFFER, rb);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT32F, w, h);
    gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, rb);
  }
  gl.drawBuffers(textures.map((_, i) => gl.COLOR_ATTACHMENT0 + i));
  const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
  if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`framebuffer incomplete (${status})`);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  return { fbo, textures, w, h };
}

/**
 * @param {GL} gl
 * @param {Target | null} t null: the canvas
 */
export function bindTarget(gl, t) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, t ? t.fbo : null);
  gl.viewport(0, 0, t ? t.w : gl.drawingBufferWidth, t ? t.h : gl.drawingBufferHeight);
}

/**
 * Read one colour attachment as float RGBA (rows bottom-up, as GL stores them).
 * @param {GL} gl
 * @param {Target} t
 * @param {number} attachment
 * @param {Float32Array} [out]
 */
export function readFloats(gl, t, attachment, out) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, t.fbo);
  gl.readBuffer(gl.COLOR_ATTACHMENT0 + attachment);
  const data = out || new Float32Array(t.w * t.h * 4);
  gl.readPixels(0, 0, t.w, t.h, gl.RGBA, gl.FLOAT, data);
  return data;
}

// Wait until the GPU has finished what was issued (one texel read back: gl.finish() does not block in Chrome).
const probeF = new Float32Array(4);
const probeU = new Uint8Array(4);
/**
 * @param {GL} gl
 * @param {Target | null} [t] null: the canvas
 * @param {number} [attachment]
 */
export function sync(gl, t = null, attachment = 0) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, t ? t.fbo : null);
  if (t) {
    gl.readBuffer(gl.COLOR_ATTACHMENT0 + attachment);
    gl.readPixels(0, 0, 1, 1, gl.RGBA, t.textures[attachment].internal === gl.RGBA8 ? gl.UNSIGNED_BYTE : gl.FLOAT,
      t.textures[attachment].internal === gl.RGBA8 ? probeU : probeF);
  } else {
    gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, probeU);
  }
}

/** @param {GL} gl */
export function fullscreen(gl) {
  gl.disable(gl.DEPTH_TEST);
  gl.disable(gl.CULL_FACE);
  gl.drawArrays(gl.TRIANGLES, 0, 3);
}

/**
 * The programs `names` of shaders.json's (web3d.shaders.page_shaders), compiled, by name.
 * @template {string} N
 * @param {GL} gl
 * @param {Shaders} shaders
 * @param {readonly N[]} names
 * @returns {Record<N, Program>}
 */
export function programs(gl, shaders, names) {
  return /** @type {Record<N, Program>} */ (Object.fromEntries(names.map((name) => {
    const src = shaders.programs[name];
    if (!src) throw new Error(`shaders.json has no program ${name}: export the assets again`);
    return [name, program(gl, src.vertex, src.fragment)];
  })));
}

/**
 * One full-screen pass of `prog` into `tgt` (null: the canvas): `textures` {uniform: texture} on units 4, 5, ...
 * @param {GL} gl
 * @param {Program} prog
 * @param {Target | null} tgt
 * @param {Record<string, WebGLTexture>} textures
 * @param {Record<string, UniformValue>} [uniforms]
 */
export function pass(gl, prog, tgt, textures, uniforms = {}) {
  bindTarget(gl, tgt);
  gl.useProgram(prog.p);
  bindTextures(gl, prog, Object.fromEntries(Object.entries(textures).map(([k, t], i) => [k, [4 + i, t]])));
  setUniforms(gl, prog, uniforms);
  fullscreen(gl);
}

// Colour attachment `attachment` of target `src` copied into `dst`'s first, upside down: GL's rows (row 0 at the
// bottom, as the page draws its frames) to image rows (row 0 at the top, as the warps read maps), and back.
/**
 * @param {GL} gl
 * @param {Target} src
 * @param {number} attachment
 * @param {Target} dst
 */
export function copyFlipped(gl, src, attachment, dst) {
  gl.bindFramebuffer(gl.READ_FRAMEBUFFER, src.fbo);
  gl.readBuffer(gl.COLOR_ATTACHMENT0 + attachment);
  gl.bindFramebuffer(gl.DRAW_FRAMEBUFFER, dst.fbo);
  gl.blitFramebuffer(0, 0, src.w, src.h, 0, dst.h, dst.w, 0, gl.COLOR_BUFFER_BIT, gl.NEAREST);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
}

/**
 * @param {GL} gl
 * @param {Program} prog
 * @param {Record<string, [number, WebGLTexture]>} units {uniformName: [unit, texture]}; units 1 and 3 belong to
 *   the shadow map's samplers
 */
export function bindTextures(gl, prog, units) {
  for (const [name, [unit, tex]] of Object.entries(units)) {
    gl.activeTexture(gl.TEXTURE0 + unit);
    gl.bindTexture(gl.TEXTURE_2D, tex);
    const u = prog.uniforms[name];
    if (u) gl.uniform1i(u.loc, unit);
  }
}

/** @param {number[]} values */
export function median(values) {
  if (!values.length) return NaN;
  const s = [...values].sort((a, b) => a - b);
  const m = s.length >> 1;
  return s.length % 2 ? s[m] : 0.5 * (s[m - 1] + s[m]);
}
