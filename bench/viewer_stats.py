"""What ``bench web`` measures of one replay (:class:`web3d.headless.Segment`), from the page's own records
(``viewer.frames``, ``viewer.maps``, and the recording of every frame drawn: its camera and light), per system:

- ``frame_ms`` by phase: ``all`` (the pane's whole time per frame), ``idle`` (no map in flight at any time of the
  frame), ``in_flight`` (drawn while a map was being made: the frame that sent the request, after sending it, and
  the frames after it until the one it lands in; the request's own synchronous half, GIGAN's G-buffer pass and
  encoding, is left out: it is the map's ``gi_render``), ``landing`` (a map landed: decoded, bound, first warped);
- ``frames_during_map``: per map, the frames drawn while it was made (from its request's frame to the one
  before it landed; ``min`` and ``median``);
- ``map_age_ms`` and ``map_age_frames``: per frame, the age of the map it showed (since its view was captured);
- ``perceived_ms``: per frame that moved the camera, the time to the first frame (it or a later one) showing a
  map within the GI tree's tolerance of its view (:func:`baseline_cloudbaking.client.perceived_latency`, the
  cloud clients' own measure; ``censored``: moved frames no map of the run served), and ``in_tolerance``;
- per map, each stage (``stat = map``) and each stage's median and p95; ``hit_rate`` for cloud baking;
- the checks, as ``stat = target_met`` rows (1 met, 0 not, NaN not measured).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from gicore.camera import Camera
from gicore.results import Results

GIGAN, CLOUD = "gigan", "cloud_baking"
#: The page's key of each system's statistics in a frame record.
PANES = {GIGAN: "gigan", CLOUD: "cloud"}
STAGES = {
    GIGAN: ("gi_render", "inference", "di", "warp", "blend"),
    CLOUD: ("transmission", "server", "decode", "di", "warp", "blend"),
}
PHASES = ("all", "idle", "in_flight", "landing")
#: The check: GIGAN's frame-time p95 with a map in flight at most this times its p95 without.
IN_FLIGHT_BOUND = 2.0


class Held(NamedTuple):
    """A map as perceived_latency reads one: the GI camera it was made at and the frame that requested it."""

    camera: Camera
    frame: int


@dataclass(frozen=True)
class Replayed:
    """One replay's records: ``frames`` and ``maps`` of its segment, ``before`` the frame drawn just before it,
    ``recorded`` every frame drawn since the page loaded (index = frame index), ``profile``."""

    profile: str
    start: int
    frames: list[dict[str, Any]]
    before: dict[str, Any] | None
    maps: list[dict[str, Any]]
    recorded: list[dict[str, Any]]

    @classmethod
    def of(cls, segment: Any, frames: list[dict], maps: list[dict], recorded: list[dict]) -> Replayed:
        (f0, f1), (m0, m1) = segment.frames, segment.maps
        before = frames[f0 - 1] if f0 else None
        return cls(segment.profile, f0, frames[f0:f1], before, maps[m0:m1], recorded)


def phases(run: Replayed, pane: str) -> dict[str, list[float]]:
    """The pane's frame times (ms) by phase (module docstring)."""
    out: dict[str, list[float]] = {p: [] for p in PHASES}
    in_flight = bool(run.before and run.before[pane] and run.before[pane]["inflight"])
    for f in run.frames:
        s = f[pane]
        out["all"].append(s["ms"])
        if s["landed"]:
            out["landing"].append(s["ms"])
        elif s["sent"] or in_flight:
            out["in_flight"].append(s["ms"] - s["request_ms"])
        else:
            out["idle"].append(s["ms"])
        in_flight = s["inflight"]
    return out


def frames_during(run: Replayed, system: str) -> dict[int, int]:
    """Per map of ``system`` (by the frame that requested it): the frames drawn while it was made."""
    pane = PANES[system]
    landed = {}
    for i, f in enumerate(run.frames, run.start):
        s = f[pane]
        if s["landed"] and s["map_frame"] is not None:
            landed.setdefault(s["map_frame"], i)
    return {m["frame"]: landed[m["frame"]] - m["frame"] for m in run.maps if m["system"] == system}


def gi_camera(frame: dict[str, Any], gi_fov: float, n: int) -> Camera:
    c = frame["camera"]
    return Camera(c["eye"], c["target"], c["up"], gi_fov, c["near"], c["far"], width=n, height=n)


def perceived(run: Replayed, system: str, gi_fov: float, n: int, cell_size: float | None) -> list[dict[str, Any]]:
    """Per frame of the replay that moved the camera or the light: :func:`perceived_latency`'s row."""
    from baseline_cloudbaking.client_run import perceived_latency
    from baseline_cloudbaking.viewpoints import Tolerance, light_cell

    pane, rec = PANES[system], run.recorded
    held: dict[int, Held] = {}

    def cell(i: int) -> Any:
        return light_cell(rec[i]["light"], cell_size)

    views, shown, moved = [], [], []
    for i, f in enumerate(run.frames, run.start):
        views.append((gi_camera(rec[i], gi_fov, n), cell(i)))
        k = f[pane]["map_frame"]
        gi = None if k is None else held.setdefault(k, Held(gi_camera(rec[k], gi_fov, n), k))
        shown.append((f["t"] / 1e3, (f["t"] + f["frame_ms"]) / 1e3, gi, None if k is None else cell(k)))
        moved.append(i == 0 or any(rec[i][key] != rec[i - 1][key] for key in ("camera", "light")))
    rows = perceived_latency(views, shown, Tolerance())  # type: ignore[arg-type]  # the servers' default tolerance
    return [row for row, m in zip(rows, moved) if m]


def _ages(run: Replayed, pane: str, key: str) -> list[float]:
    return [f[pane][key] for f in run.frames if f[pane][key] is not None]


def _summary(res: Results, metric: str, values: list[float], unit: str, **where: Any) -> None:
    for stat, value in (("median", np.median(values)), ("p95", np.percentile(values, 95))):
        res.add(metric=metric, value=float(value), unit=unit, stat=stat, **where)


def record_system(res: Results, run: Replayed, system: str, scene: dict[str, Any], common: dict[str, Any]) -> None:
    """The rows of ``system`` in one replay (module docstring); ``scene``: name, gi_fov, resolution, light cell."""
    pane, where = PANES[system], {"system": system, "scene": scene["name"]} | common | {"profile": run.profile}
    maps = [m for m in run.maps if m["system"] == system]
    for stage in (*STAGES[system], "total"):
        values = [m["total"] if stage == "total" else m["stages"][stage] for m in maps]
        if values:
            res.add_timing(metric=stage, samples_s=[v / 1e3 for v in values], **where)
        for m, v in zip(maps, values):
            res.add(metric=stage, value=v, unit="ms", stat="map", **where, frame=m["frame"])
    for phase, values in phases(run, pane).items():
        if values:
            res.add_timing(metric="frame_ms", samples_s=[v / 1e3 for v in values], **where, phase=phase)
    during = frames_during(run, system)
    for frame, count in during.items():
        res.add(metric="frames_during_map", value=count, unit="frames", stat="map", **where, frame=frame)
    if during:
        for stat, value in (("min", min(during.values())), ("median", float(np.median(list(during.values()))))):
            res.add(metric="frames_during_map", value=value, unit="frames", stat=stat, **where)
    ages = _ages(run, pane, "map_age_ms")
    if ages:
        res.add_timing(metric="map_age_ms", samples_s=[v / 1e3 for v in ages], **where)
        _summary(res, "map_age_frames", _ages(run, pane, "map_age_frames"), "frames", **where)
    rows = perceived(run, system, scene["gi_fov"], scene["resolution"], scene["light_cell"])
    served = [r["perceived_ms"] for r in rows if r["perceived_ms"] != ""]
    if served:
        res.add_timing(metric="perceived_ms", samples_s=[v / 1e3 for v in served], **where)
    res.add(metric="censored", value=len(rows) - len(served), unit="frames", **where)
    if rows:
        share = float(np.mean([r["in_tolerance"] for r in rows]))
        res.add(metric="in_tolerance", value=share, unit="fraction", **where)
    if system == CLOUD and maps:
        res.add(metric="hit_rate", value=sum(bool(m.get("hit")) for m in maps) / len(maps), unit="fraction", **where)


def record_checks(res: Results, run: Replayed, scene: str, common: dict[str, Any]) -> None:
    """The two checks on GIGAN's pane in one replay, as ``target_met`` rows (NaN: not measured in this replay)."""
    where = {"system": GIGAN, "scene": scene} | common | {"profile": run.profile}
    by_phase = phases(run, PANES[GIGAN])
    flight, idle = by_phase["in_flight"], by_phase["idle"]
    measured = float(np.percentile(flight, 95)) if flight else math.nan
    baseline = float(np.percentile(idle, 95)) if idle else math.nan
    ratio = measured / baseline if baseline > 0 else math.nan
    met = math.nan if math.isnan(ratio) else float(ratio <= IN_FLIGHT_BOUND)
    res.add(metric="frame_ms", value=met, unit="bool", stat="target_met", **where, ratio=ratio, measured=measured,
            bound=IN_FLIGHT_BOUND * baseline, target=f"frame-time p95 with a map in flight <= {IN_FLIGHT_BOUND:g} x "
            "its p95 with none (ms)")  # fmt: skip
    during = frames_during(run, GIGAN)
    fewest = min(during.values()) if during else math.nan
    met = math.nan if not during else float(fewest >= 1)
    res.add(metric="frames_during_map", value=met, unit="bool", stat="target_met", **where, measured=fewest,
            bound=1, target="frames drawn while each map was made: fewest >= 1")  # fmt: skip
