// The light a person moves (a slider per axis of light_range that varies, and Shift+drag over the canvases) and
// the shadow-map setups the server fits for each light (GET /v1/shadow), cached by light. A frame draws the
// newest light whose setup has arrived, so its shadows always match it.

import { clampLight } from "./camera.js";

/** @typedef {import("./camera.js").Vec3} Vec3 */
/**
 * A light's shadow-map setup (web3d.export.shadow_setup): the atlas's size, one view-projection per face, ...
 * @typedef {{atlas: [number, number], tile: number, views: Float32Array[] | number[][], far: number,
 *   texel: number[], blocker_min: number}} ShadowSetup
 */

/** @param {number[]} light */
const key = (light) => light.join(",");
// Setups kept, the least recently used dropped past it (a light dragged for an hour makes one per step): more than a
// replay's lights, whose setups are fetched before it plays.
const CACHED = 4096;
// A key press on a light slider moves the light by this share of its range (the slider's own step is finer, for
// dragging it).
const KEY_STEP = 1 / 20;
/** @type {Record<string, number>} */
const KEYS = { ArrowRight: 1, ArrowUp: 1, ArrowLeft: -1, ArrowDown: -1 };

export class ShadowSetups {
  constructor() {
    /** @type {Map<string, ShadowSetup>} */
    this.cache = new Map();
    /** @type {Promise<void> | null} */
    this.fetching = null;
  }

  /**
   * The setup for `light`, or null while it is fetched (one fetch at a time; `onError` hears a failed one).
   * @param {number[]} light
   * @param {(error: unknown) => void} onError
   * @returns {ShadowSetup | null}
   */
  get(light, onError) {
    const k = key(light);
    const kept = this.cache.get(k);
    if (kept) return this.remember(k, kept);
    if (!this.fetching) {
      this.fetching = this.fetch(light)
        .catch(onError)
        .finally(() => (this.fetching = null));
    }
    return null;
  }

  /** @param {number[]} light */
  async fetch(light) {
    const k = key(light);
    const r = await fetch(`/v1/shadow?light=${encodeURIComponent(k)}`);
    if (!r.ok) throw new Error(`/v1/shadow?light=${k} answered ${r.status}: ${await r.text()}`);
    this.remember(k, await r.json());
  }

  /**
   * `setup` cached as the most recently used, the least recently used dropped past CACHED; returns it.
   * @param {string} k
   * @param {ShadowSetup} setup
   */
  remember(k, setup) {
    this.cache.delete(k);
    this.cache.set(k, setup);
    const oldest = this.cache.keys().next().value; // a Map keeps insertion order
    if (this.cache.size > CACHED && oldest !== undefined) this.cache.delete(oldest);
    return setup;
  }

  /**
   * Every setup of `lights` fetched, a few at a time (a replay's lights, before it starts).
   * @param {number[][]} lights
   * @param {number} [parallel]
   */
  async prefetch(lights, parallel = 4) {
    const todo = [...new Set(lights.map(key))].filter((k) => !this.cache.has(k)).map((k) => k.split(",").map(Number));
    const worker = async () => {
      for (let light = todo.pop(); light; light = todo.pop()) await this.fetch(light);
    };
    await Promise.all(Array.from({ length: parallel }, worker));
  }
}

// The requested light: two sliders (x, y; an arrow key moves it KEY_STEP of the range) and Shift+drag on `surface`
// (a canvas width moves the light across its range); z stays put. The frame loop reads `value`.
export class LightInput {
  /**
   * @param {number[][]} range scene.json's light_range: [low, high]
   * @param {number[]} light the first
   * @param {HTMLInputElement[]} sliders x, y
   * @param {HTMLElement} surface the element over both canvases
   */
  constructor(range, light, sliders, surface) {
    this.range = range;
    this.sliders = sliders;
    /** @type {number[]} */
    this.value = [];
    sliders.forEach((slider, axis) => {
      const [lo, hi] = [range[0][axis], range[1][axis]];
      Object.assign(slider, { min: String(lo), max: String(hi), step: String((hi - lo) / 1000 || 1) });
      slider.disabled = !(hi > lo);
      slider.addEventListener("input", () => this.input(axis, Number(slider.value)));
      slider.addEventListener("keydown", (e) => {
        if (!(e.key in KEYS) || slider.disabled) return;
        e.preventDefault(); // instead of the slider's own step
        this.input(axis, this.value[axis] + KEYS[e.key] * KEY_STEP * (hi - lo));
      });
    });
    this.set(light);
    this.dragOn(surface);
  }

  /** @param {number[]} light */
  set(light) {
    this.value = clampLight(light, this.range);
    this.sliders.forEach((slider, axis) => (slider.value = String(this.value[axis])));
    return this.value;
  }

  /**
   * @param {number} axis
   * @param {number} v
   */
  input(axis, v) {
    const light = [...this.value];
    light[axis] = v;
    this.set(light);
  }

  // Shift+drag: captured before the orbit controls see the pointer (they pan on Shift+drag otherwise).
  /** @param {HTMLElement} surface */
  dragOn(surface) {
    /** @type {number[] | null} */
    let last = null;
    /** @param {PointerEvent} e */
    const move = (e) => {
      if (!last) return;
      const w = surface.clientWidth / 2 || 1; // one canvas
      const [lo, hi] = this.range;
      const light = [...this.value];
      light[0] += ((e.clientX - last[0]) / w) * (hi[0] - lo[0]);
      light[1] -= ((e.clientY - last[1]) / w) * (hi[1] - lo[1]);
      last = [e.clientX, e.clientY];
      this.set(light);
    };
    const up = () => {
      last = null;
      document.removeEventListener("pointermove", move);
      document.removeEventListener("pointerup", up);
    };
    /** @type {HTMLElement} */ (surface.parentElement).addEventListener("pointerdown", (e) => {
      if (!e.shiftKey || e.button !== 0 || !surface.contains(/** @type {Node} */ (e.target))) return;
      e.stopPropagation(); // the controls on `surface` never see it
      last = [e.clientX, e.clientY];
      document.addEventListener("pointermove", move);
      document.addEventListener("pointerup", up);
    }, { capture: true });
  }
}
