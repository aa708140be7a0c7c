// The scene's raster passes in WebGL2: gicore.gl.GLRenderer's passes (its GLSL, exported by web3d.export),
// drawn unflipped (GL's bottom-up rows; the canvas shows them the right way up).

import { program, setUniforms, target, bindTarget, texture } from "./glutil.js";

/** @typedef {import("./glutil.js").GL} GL */
/** @typedef {import("./glutil.js").Program} Program */
/** @typedef {import("./glutil.js").Target} Target */
/** @typedef {import("./glutil.js").Texture} Texture */
/** @typedef {import("./glutil.js").UniformValue} UniformValue */
/** @typedef {import("./camera.js").Vec3} Vec3 */
/** @typedef {import("./camera.js").WithMatrices<Float32Array>} GLCamera */
/** @typedef {import("./light.js").ShadowSetup} ShadowSetup */
/** @typedef {{tex: Texture, fbo: WebGLFramebuffer, key: string, setup: ShadowSetup}} ShadowMap */
/**
 * scene.json's camera: the path's first view, both fields of view, the clip planes.
 * @typedef {{eye: Vec3, target: Vec3, up: Vec3, local_fov: number, gi_fov: number, near: number,
 *   far: number}} SceneCamera
 */
/**
 * A frame as the passes draw it: its local and GI cameras, its light and that light's shadow setup.
 * @typedef {{local: GLCamera, gi: GLCamera, light: number[], shadow: ShadowSetup}} Frame
 */
/**
 * scene.json (web3d.export): the byte ranges of scene.bin, the passes' programs, the materials, the light, the
 * camera and its envelope.
 * @typedef {object} SceneHeader
 * @property {string} scene
 * @property {number} resolution
 * @property {number} triangles
 * @property {number} vertex_floats
 * @property {{offset: number, count: number}} vertices
 * @property {{offset: number, count: number, culled: number}} indices
 * @property {{offset: number, count: number}} shadow_vertices
 * @property {{offset: number, count: number}} shadow_indices
 * @property {Record<string, import("./glutil.js").ProgramSource>} programs
 * @property {number[]} materials
 * @property {{intensity: number, size: number, samples: number}} light
 * @property {number} eta
 * @property {SceneCamera} camera
 * @property {import("./camera.js").Envelope} navigation
 * @property {number[][]} light_range
 */

const UNIT_SHADOW = 1; // the depth-comparison sampler's texture unit
const UNIT_SHADOW_RAW = 3; // the same texture without comparison (PCSS blocker search; area lights)

export class SceneRenderer {
  /**
   * @param {GL} gl
   * @param {SceneHeader} scene
   * @param {ArrayBuffer} bin scene.bin
   */
  constructor(gl, scene, bin) {
    this.gl = gl;
    this.scene = scene;
    this.n = scene.resolution;
    const floats = new Float32Array(bin, scene.vertices.offset, scene.vertices.count * scene.vertex_floats);
    const indices = new Uint32Array(bin, scene.indices.offset, scene.indices.count);
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    const vbo = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, vbo);
    gl.bufferData(gl.ARRAY_BUFFER, floats, gl.STATIC_DRAW);
    const stride = scene.vertex_floats * 4;
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, stride, 0);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribPointer(1, 3, gl.FLOAT, false, stride, 12);
    gl.enableVertexAttribArray(2);
    gl.vertexAttribPointer(2, 4, gl.FLOAT, false, stride, 24);
    // in_uv stays a constant: every pass either ignores it or projects the coordinates in the vertex shader
    const ibo = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, indices, gl.STATIC_DRAW);
    gl.bindVertexArray(null);
    // the shadow map's casters: positions only, decimated as GLRenderer's SHADOW_LOD
    const sv = scene.shadow_vertices;
    const si = scene.shadow_indices;
    this.shadowVao = gl.createVertexArray();
    gl.bindVertexArray(this.shadowVao);
    gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(bin, sv.offset, sv.count * 3), gl.STATIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 12, 0);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer());
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint32Array(bin, si.offset, si.count), gl.STATIC_DRAW);
    gl.bindVertexArray(null);

    /** @type {Record<string, Program>} */
    this.programs = {};
    for (const [name, src] of Object.entries(scene.programs)) this.programs[name] = program(gl, src.vertex, src.fragment);
    this.materials = new Float32Array(scene.materials);
    const n = this.n;
    // targets: GI camera (albedo, normal, position, depth, DI), local DI, local uv pass (uv, position, code)
    this.giTarget = target(gl, n, n, [gl.RGBA32F, gl.RGBA32F, gl.RGBA32F, gl.R32F, gl.RGBA32F]);
    this.diTarget = target(gl, n, n, [gl.RGBA32F]);
    this.uvTarget = target(gl, n, n, [gl.RGBA32F, gl.RGBA32F, gl.R32F]);

    const compare = gl.createSampler();
    const raw = gl.createSampler();
    for (const s of [compare, raw]) {
      gl.samplerParameteri(s, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.samplerParameteri(s, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    }
    gl.samplerParameteri(compare, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.samplerParameteri(compare, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.samplerParameteri(compare, gl.TEXTURE_COMPARE_MODE, gl.COMPARE_REF_TO_TEXTURE);
    gl.samplerParameteri(compare, gl.TEXTURE_COMPARE_FUNC, gl.LEQUAL);
    gl.samplerParameteri(raw, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.samplerParameteri(raw, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.bindSampler(UNIT_SHADOW, compare);
    gl.bindSampler(UNIT_SHADOW_RAW, raw);
    /** @type {ShadowMap | null} */
    this.shadow = null;
  }

  /**
   * @param {Program} prog
   * @param {Record<string, UniformValue>} uniforms
   * @param {Target} tgt
   */
  drawScene(prog, uniforms, tgt) {
    const gl = this.gl;
    bindTarget(gl, tgt);
    gl.clearColor(0, 0, 0, 0);
    gl.clearDepth(1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.useProgram(prog.p);
    setUniforms(gl, prog, uniforms);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
    gl.bindVertexArray(this.vao);
    const { count, culled } = this.scene.indices;
    if (culled) {
      gl.enable(gl.CULL_FACE); // closed meshes: back faces are never visible from outside
      gl.cullFace(gl.BACK);
      gl.frontFace(gl.CCW);
      gl.drawElements(gl.TRIANGLES, culled, gl.UNSIGNED_INT, 0);
      gl.disable(gl.CULL_FACE);
    }
    if (count > culled) gl.drawElements(gl.TRIANGLES, count - culled, gl.UNSIGNED_INT, culled * 4);
    gl.bindVertexArray(null);
  }

  /**
   * The shadow-map atlas for the frame's light (rendered when the light moved, as GLRenderer does).
   * @param {Frame} frame
   * @returns {ShadowMap}
   */
  ensureShadow(frame) {
    const gl = this.gl;
    const key = frame.light.join(",");
    if (this.shadow && this.shadow.key === key) return this.shadow;
    const setup = frame.shadow;
    const [aw, ah] = setup.atlas;
    if (!this.shadow || this.shadow.tex.w !== aw || this.shadow.tex.h !== ah) {
      const tex = texture(gl, aw, ah, gl.DEPTH_COMPONENT32F);
      const fbo = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, tex, 0);
      gl.drawBuffers([gl.NONE]);
      this.shadow = { tex, fbo, key, setup };
    }
    const fbo = this.shadow.fbo;
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.viewport(0, 0, aw, ah);
    gl.clearDepth(1);
    gl.clear(gl.DEPTH_BUFFER_BIT);
    const prog = this.programs.shadow;
    gl.useProgram(prog.p);
    setUniforms(gl, prog, { u_light: frame.light, u_far: setup.far });
    gl.enable(gl.DEPTH_TEST);
    gl.disable(gl.CULL_FACE);
    gl.bindVertexArray(this.shadowVao);
    setup.views.forEach((vp, face) => {
      gl.viewport((face % 3) * setup.tile, Math.floor(face / 3) * setup.tile, setup.tile, setup.tile);
      setUniforms(gl, prog, { u_vp: vp });
      gl.drawElements(gl.TRIANGLES, this.scene.shadow_indices.count, gl.UNSIGNED_INT, 0);
    });
    gl.bindVertexArray(null);
    return Object.assign(this.shadow, { key, setup });
  }

  /**
   * @param {Frame} frame
   * @param {ShadowMap} shadow its shadow map
   * @returns {Record<string, UniformValue>}
   */
  diUniforms(frame, shadow) {
    const gl = this.gl;
    const { setup: s, tex } = shadow;
    const light = this.scene.light;
    const k = light.size > 0 ? light.samples : 1;
    const vps = new Float32Array(16 * 6);
    s.views.forEach((v, i) => vps.set(v, 16 * i));
    const texel = new Float32Array(6);
    texel.set(s.texel);
    gl.activeTexture(gl.TEXTURE0 + UNIT_SHADOW);
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.activeTexture(gl.TEXTURE0 + UNIT_SHADOW_RAW);
    gl.bindTexture(gl.TEXTURE_2D, tex);
    return {
      u_light: frame.light,
      u_intensity: light.intensity / (k * k),
      u_radiance: light.size > 0 ? light.intensity / light.size ** 2 : 0,
      u_light_size: light.size,
      u_eta: this.scene.eta,
      u_materials: this.materials,
      u_shadow: UNIT_SHADOW,
      u_shadow_raw: UNIT_SHADOW_RAW,
      u_shadow_far: s.far,
      u_shadow_vp: vps,
      u_shadow_texel: texel,
      u_shadow_size: s.tile,
      u_blocker_min: s.blocker_min,
    };
  }

  /** @param {GLCamera} cam */
  cameraUniforms(cam) {
    return { u_view_proj: cam.view_proj, u_view: cam.view, u_eye: cam.eye, u_project_uv: false };
  }

  /**
   * @param {string} name
   * @param {ShadowMap} shadow
   */
  variant(name, shadow) {
    return this.programs[shadow.setup.views.length === 6 ? `${name}_cube` : name];
  }

  /**
   * DI + G-buffers at the GI camera (one pass, five targets): GIGAN's generator input.
   * @param {Frame} frame
   */
  renderGI(frame) {
    const shadow = this.ensureShadow(frame);
    const u = { ...this.cameraUniforms(frame.gi), ...this.diUniforms(frame, shadow) };
    this.drawScene(this.variant("di_gbuffer", shadow), u, this.giTarget);
    return this.giTarget;
  }

  /**
   * The local camera's DI (alpha 1 on surfaces: the surface mask).
   * @param {Frame} frame
   */
  renderDI(frame) {
    const shadow = this.ensureShadow(frame);
    const u = { ...this.cameraUniforms(frame.local), ...this.diUniforms(frame, shadow) };
    this.drawScene(this.variant("di", shadow), u, this.diTarget);
    return this.diTarget;
  }

  // The structure-aware warp's pass: the GI camera's clip (x, y) per vertex (eq. 5, projected in the vertex
  // shader), interpolated, with the world position and the surface code.
  /**
   * @param {Frame} frame
   * @param {Float32Array} giViewProj
   */
  renderUV(frame, giViewProj) {
    const u = { ...this.cameraUniforms(frame.local), u_project_uv: true, u_uv_proj: giViewProj };
    this.drawScene(this.programs.uv, u, this.uvTarget);
    return this.uvTarget;
  }
}
