// The page's camera maths: gicore.camera.Camera's matrices in float64 (plain JS numbers), column-major as WebGL
// takes them, and the clamp of a camera to the scene's navigable envelope (scene.json "navigation").
//
//   view = diag(-1, 1, -1, 1) @ inverse(to_world)   (Mitsuba's look-at: +x left, +y up, +z forward)
//   proj = GL perspective, fx = 1 / tan(fov_x / 2), fy = fx (the images are square)

/** @typedef {number[]} Vec3 */
/** @typedef {{eye: Vec3, target: Vec3}} Pose */
/**
 * scene.json's navigable envelope (gicore.paths.navigation).
 * @typedef {{target: Vec3, target_wobble: number, radius: [number, number], height: [number, number],
 *   azimuth: [number, number] | null}} Envelope
 */
/** @typedef {{eye: Vec3, target: Vec3, up: Vec3, fov: number, near: number, far: number}} CameraSpec */
/**
 * @template M
 * @typedef {CameraSpec & {view: M, proj: M, view_proj: M}} WithMatrices
 */

/** @type {(a: Vec3, b: Vec3) => Vec3} */
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
/** @type {(a: Vec3, b: Vec3) => number} */
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
/** @type {(a: Vec3, b: Vec3) => Vec3} */
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
/** @type {(a: Vec3) => Vec3} */
const normalize = (a) => {
  const n = Math.hypot(a[0], a[1], a[2]);
  return [a[0] / n, a[1] / n, a[2] / n];
};

/**
 * Camera.view(): the inverse of the rigid look-at frame [left, up', d | eye], its x and z rows negated.
 * @param {Vec3} eye
 * @param {Vec3} target
 * @param {Vec3} up
 */
export function viewMatrix(eye, target, up) {
  const d = normalize(sub(target, eye));
  const left = normalize(cross(up, d));
  const newUp = cross(d, left);
  const rows = [
    [-left[0], -left[1], -left[2], dot(left, eye)],
    [newUp[0], newUp[1], newUp[2], -dot(newUp, eye)],
    [-d[0], -d[1], -d[2], dot(d, eye)],
    [0, 0, 0, 1],
  ];
  return columnMajor(rows);
}

/**
 * Camera.proj(): the horizontal fov's focal length on both axes (width = height).
 * @param {number} fov
 * @param {number} near
 * @param {number} far
 */
export function projMatrix(fov, near, far) {
  const fx = 1 / Math.tan((fov * Math.PI) / 360);
  const rows = [
    [fx, 0, 0, 0],
    [0, fx, 0, 0],
    [0, 0, -(far + near) / (far - near), (-2 * far * near) / (far - near)],
    [0, 0, -1, 0],
  ];
  return columnMajor(rows);
}

/** @param {number[][]} rows */
function columnMajor(rows) {
  return [0, 1, 2, 3].flatMap((c) => rows.map((r) => r[c]));
}

/**
 * a @ b for column-major 4x4 arrays.
 * @param {number[]} a
 * @param {number[]} b
 */
export function multiply(a, b) {
  const out = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[4 * k + r] * b[4 * c + k];
      out[4 * c + r] = s;
    }
  }
  return out;
}

/**
 * {eye, target, up, fov, near, far} with its view, proj and view_proj (float64, column-major).
 * @param {CameraSpec} cam
 * @returns {WithMatrices<number[]>}
 */
export function withMatrices(cam) {
  const view = viewMatrix(cam.eye, cam.target, cam.up);
  const proj = projMatrix(cam.fov, cam.near, cam.far);
  return { ...cam, view, proj, view_proj: multiply(proj, view) };
}

/**
 * The same camera as the WebGL passes take it: matrices as Float32Array.
 * @param {CameraSpec} cam
 * @returns {WithMatrices<Float32Array>}
 */
export function forGL(cam) {
  const m = withMatrices(cam);
  /** @param {number[]} a */
  const f32 = (a) => new Float32Array(a);
  return { ...m, view: f32(m.view), proj: f32(m.proj), view_proj: f32(m.view_proj) };
}

/** @type {(v: number, range: number[]) => number} */
const clampTo = (v, [lo, hi]) => Math.min(Math.max(v, lo), hi);

/**
 * The look-at target within target_wobble of the envelope's target in x and y (its z stays the envelope's).
 * @param {Vec3} target
 * @param {Envelope} nav
 * @returns {Vec3}
 */
function clampTarget(target, nav) {
  const [tx, ty, tz] = nav.target;
  const w = nav.target_wobble;
  return [clampTo(target[0], [tx - w, tx + w]), clampTo(target[1], [ty - w, ty + w]), tz];
}

// The eye's horizontal distance and azimuth (degrees, atan2(x - tx, z - tz)) around the envelope's target
// within their ranges, its height within its range. A value already inside is returned unchanged, bit for bit.
/**
 * @param {Vec3} eye
 * @param {Envelope} nav
 * @returns {Vec3}
 */
function clampEye(eye, nav) {
  const [tx, , tz] = nav.target;
  const dx = eye[0] - tx;
  const dz = eye[2] - tz;
  const radius = Math.hypot(dx, dz);
  const azimuth = (Math.atan2(dx, dz) * 180) / Math.PI;
  const r = clampTo(radius, nav.radius);
  const a = nav.azimuth ? clampAzimuth(azimuth, nav.azimuth) : azimuth;
  const y = clampTo(eye[1], nav.height);
  if (r === radius && a === azimuth) return [eye[0], y, eye[2]];
  const rad = (a * Math.PI) / 180;
  return [tx + r * Math.sin(rad), y, tz + r * Math.cos(rad)];
}

/**
 * An azimuth (degrees) into [lo, hi] (an arc that may wrap past ±180): the nearer end when outside.
 * @param {number} a
 * @param {[number, number]} range
 */
function clampAzimuth(a, [lo, hi]) {
  /** @param {number} x */
  const wrap = (x) => ((((x - lo) % 360) + 360) % 360);
  const span = wrap(hi);
  const off = wrap(a);
  if (off <= span) return a;
  return off - span < 360 - off ? hi : lo;
}

/**
 * {eye, target} inside the navigable envelope.
 * @param {Pose} pose
 * @param {Envelope} nav
 * @returns {Pose}
 */
export function clampToNavigation({ eye, target }, nav) {
  return { eye: clampEye(eye, nav), target: clampTarget(target, nav) };
}

/**
 * A light inside light_range (per axis).
 * @param {number[]} light
 * @param {number[][]} range [low, high]
 */
export function clampLight(light, [lo, hi]) {
  return light.map((v, i) => clampTo(v, [lo[i], hi[i]]));
}
