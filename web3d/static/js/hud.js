// The HUD: per pane, its GI maps' stages (the last and the median of its recent ones, ms; performance.now after a
// GPU sync) and, for the last drawn frame, the frame's time, the age of the map it shows and whether a request is
// in flight; the systems' ratio of median totals; a status line. Written as text and elements, never as HTML.

import { median } from "./glutil.js";
import { RECENT_MAPS } from "./pane.js";
import { byId } from "./dom.js";

/** @typedef {import("./pane.js").Pane<any>} Pane */
/** @typedef {import("./pane.js").PaneStats} PaneStats */
/** @typedef {import("./pane.js").MapRecord} MapRecord */

/** @param {number | undefined} v */
const f1 = (v) => (v !== undefined && Number.isFinite(v) ? v.toFixed(1) : "—");

/**
 * A table row of `cells` (text; a cell's `bold` text in a <b>), each a `tag` cell.
 * @param {"td" | "th"} tag
 * @param {(string | {bold: string})[]} cells
 */
function tableRow(tag, cells) {
  const tr = document.createElement("tr");
  for (const text of cells) {
    const cell = document.createElement(tag);
    if (typeof text === "string") cell.textContent = text;
    else cell.append(Object.assign(document.createElement("b"), { textContent: text.bold }));
    tr.append(cell);
  }
  return tr;
}

/**
 * A stage's row: its time in the last map and its median over `maps`.
 * @param {string | {bold: string}} name
 * @param {MapRecord[]} maps
 * @param {(map: MapRecord) => number | undefined} value
 */
function stageRow(name, maps, value) {
  const values = /** @type {number[]} */ (maps.map(value).filter((v) => v !== undefined && Number.isFinite(v)));
  return tableRow("td", [name, f1(maps.length ? value(maps[maps.length - 1]) : undefined), f1(median(values))]);
}

/**
 * "frame 31.2 ms · map of frame 40: 3 frames, 95 ms old · in flight"
 * @param {number} frameMs
 * @param {PaneStats} stats
 */
function liveLine(frameMs, stats) {
  const age = stats.map_frame === null ? "no map yet"
    : `map of frame ${stats.map_frame}: ${stats.map_age_frames} frames, ${f1(stats.map_age_ms ?? undefined)} ms old`;
  const state = stats.error ? `error: ${stats.error}` : stats.inflight ? "in flight" : "idle";
  return `frame ${f1(frameMs)} ms · ${age} · ${state}`;
}

export class Hud {
  /**
   * @param {object} sources what it shows
   * @param {import("./loop.js").FrameLoop} sources.loop its frames and panes
   * @param {import("./record.js").Recorder} sources.recorder
   * @param {import("./cloud_route.js").CloudRoute | null} sources.route the cloud requests' (null: cloud off)
   * @param {{backend?: string, renderer?: string}} sources.info the page's runtime and WebGL renderer
   */
  constructor({ loop, recorder, route, info }) {
    this.loop = loop;
    this.recorder = recorder;
    this.route = route;
    this.info = info;
    this.tables = [byId("hud-gigan", HTMLTableElement), byId("hud-cloud", HTMLTableElement)];
    this.live = [byId("live-gigan", HTMLElement), byId("live-cloud", HTMLElement)];
    this.ratio = byId("ratio", HTMLElement);
    this.status = byId("status", HTMLElement);
  }

  /**
   * One pane's table: its recent maps' stages (none for a pane that is off).
   * @param {HTMLTableElement} table
   * @param {Pane | null} pane
   */
  stageTable(table, pane) {
    if (!pane) {
      table.replaceChildren();
      return;
    }
    const maps = pane.recent.recent(RECENT_MAPS);
    const made = pane.recent.count;
    const span = made > maps.length ? ` (medians of the last ${maps.length})` : "";
    table.replaceChildren(tableRow("th", ["stage (ms)", "last", "median"]),
      ...pane.stages.map((s) => stageRow(s, maps, (m) => m.stages[s])),
      stageRow({ bold: "total" }, maps, (m) => m.total), tableRow("td", ["maps", `${made}${span}`]));
  }

  show() {
    const frames = this.loop.frames;
    const last = frames.last();
    this.loop.panes.forEach((pane, i) => {
      this.stageTable(this.tables[i], pane);
      const stats = last && (i ? last.cloud : last.gigan);
      if (last) this.live[i].textContent = stats ? liveLine(last.frame_ms, stats) : "";
    });
    /** @param {Pane | null} p */
    const total = (p) => median(p ? p.recent.recent(RECENT_MAPS).map((m) => m.total) : []);
    const [g, c] = this.loop.panes;
    const ratio = total(c) / total(g);
    this.ratio.textContent = Number.isFinite(ratio) ? `median total: cloud baking / GIGAN = ${ratio.toFixed(2)}` : "";
    const cloud = this.route ? ` · profile ${this.route.profile} · store ${this.route.store}` : " · cloud off";
    const rec = this.recorder.describe();
    this.status.textContent =
      `frame ${frames.count} · ${this.info.backend} · ${this.info.renderer}${cloud}${rec ? ` · ${rec}` : ""}`;
  }
}
