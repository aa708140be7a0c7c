// Navigation: three.js's OrbitControls (orbit, zoom, pan by mouse, touch and keys) on a PerspectiveCamera over both
// canvases; the page reads the eye and target from it each frame, clamped to the scene's navigable envelope. The
// three camera is never rendered: the page computes its own matrices (camera.js).

import { PerspectiveCamera } from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { clampToNavigation } from "./camera.js";

const ZOOM_STEP = 1.1;
// An arrow key's pan, in pixels of the canvases (OrbitControls' default, 7, moved the view by about 1 %), and
// Shift/Ctrl + arrow's orbit (1: 0.7° a press).
const KEY_PAN_PX = 40;
const KEY_ROTATE = 4;
/** @type {Record<string, boolean>} */
const ZOOM_KEYS = { Equal: true, NumpadAdd: true, PageUp: true, Minus: false, NumpadSubtract: false, PageDown: false };

/** @typedef {import("./camera.js").Pose} Pose */
/** @typedef {import("./camera.js").Envelope} Envelope */
/** @typedef {import("./scene.js").SceneCamera} SceneCamera */

export class Navigation {
  /**
   * @param {HTMLElement} surface the element over both canvases
   * @param {SceneCamera} camera scene.json's camera
   * @param {Envelope} nav its navigation envelope
   * @param {Pose} start
   */
  constructor(surface, camera, nav, start) {
    this.nav = nav;
    this.three = new PerspectiveCamera(camera.local_fov, 1, camera.near, camera.far); // square images
    this.three.up.set(camera.up[0], camera.up[1], camera.up[2]);
    this.controls = new OrbitControls(this.three, surface);
    this.controls.listenToKeyEvents(surface); // arrows pan, Shift/Ctrl + arrows orbit
    Object.assign(this.controls, { keyPanSpeed: KEY_PAN_PX, keyRotateSpeed: KEY_ROTATE });
    surface.addEventListener("keydown", (e) => {
      if (!(e.code in ZOOM_KEYS) || !this.controls.enabled) return;
      if (ZOOM_KEYS[e.code]) this.controls.dollyIn(ZOOM_STEP);
      else this.controls.dollyOut(ZOOM_STEP);
      e.preventDefault();
    });
    this.set(start);
  }

  /**
   * {eye, target} clamped, written to the three camera and the controls (their next update starts from it).
   * @param {Pose} pose
   * @returns {Pose}
   */
  set(pose) {
    const { eye, target } = clampToNavigation(pose, this.nav);
    this.three.position.set(eye[0], eye[1], eye[2]);
    this.controls.target.set(target[0], target[1], target[2]);
    this.three.lookAt(this.controls.target);
    return { eye, target };
  }

  /**
   * The current {eye, target}: what the controls made of a person's input, clamped (and the clamp written back).
   * @returns {Pose}
   */
  pose() {
    const p = this.three.position;
    const t = this.controls.target;
    const raw = { eye: [p.x, p.y, p.z], target: [t.x, t.y, t.z] };
    const pose = clampToNavigation(raw, this.nav);
    const moved = pose.eye.some((v, i) => v !== raw.eye[i]) || pose.target.some((v, i) => v !== raw.target[i]);
    return moved ? this.set(pose) : pose;
  }
}
