// The HUD: per pane, each GI map's stages (last and median, ms; performance.now after a GPU sync) and, per rendered
// frame, the frame's time, the age of the map it shows and whether a request is in flight; a status line.

import { median } from "./glutil.js";
import { CLOUD_STAGES, GIGAN_STAGES } from "./pane.js";

const f1 = (v) => (Number.isFinite(v) ? v.toFixed(1) : "—");

function row(name, last, values) {
  return `<tr><td>${name}</td><td>${f1(last)}</td><td>${f1(median(values))}</td></tr>`;
}

function stageTable(id, stages, maps) {
  const rows = stages.map((s) => row(s, maps.at(-1)?.stages[s], maps.map((m) => m.stages[s]).filter(Number.isFinite)));
  rows.push(row("<b>total</b>", maps.at(-1)?.total, maps.map((m) => m.total)));
  document.getElementById(id).innerHTML =
    `<tr><th>stage (ms)</th><th>last</th><th>median</th></tr>${rows.join("")}<tr><td>maps</td><td colspan=2>${maps.length}</td></tr>`;
}

// "frame 31.2 ms · map of frame 40: 3 frames, 95 ms old · in flight"
function live(id, frame, stats) {
  const el = document.getElementById(id);
  if (!stats) {
    el.textContent = "";
    return;
  }
  const age = stats.map_frame === null ? "no map yet"
    : `map of frame ${stats.map_frame}: ${stats.map_age_frames} frames, ${f1(stats.map_age_ms)} ms old`;
  const state = stats.error ? `error: ${stats.error}` : stats.inflight ? "in flight" : "idle";
  el.textContent = `frame ${f1(frame.frame_ms)} ms · ${age} · ${state}`;
}

export function showHud(viewer, recording) {
  const frames = viewer.frames;
  const last = frames.at(-1);
  const g = viewer.maps.filter((m) => m.system === "gigan");
  const c = viewer.maps.filter((m) => m.system === "cloud_baking");
  stageTable("hud-gigan", GIGAN_STAGES, g);
  stageTable("hud-cloud", CLOUD_STAGES, c);
  if (last) {
    live("live-gigan", last, last.gigan);
    live("live-cloud", last, last.cloud);
  }
  const ratio = median(c.map((m) => m.total)) / median(g.map((m) => m.total));
  document.getElementById("ratio").textContent = Number.isFinite(ratio)
    ? `median total: cloud baking / GIGAN = ${ratio.toFixed(2)}` : "";
  const cloud = viewer.profile ? ` · profile ${viewer.profile} · store ${viewer.store}` : " · cloud off";
  const rec = recording ? ` · ● recording (${viewer.recording().frames.length} frames)` : "";
  document.getElementById("status").textContent =
    `frame ${frames.length} · ${viewer.info.backend} · ${viewer.info.renderer}${cloud}${rec}`;
}
