"""The Web3D page's own records of one replay (:class:`web3d.headless.Segment`), read from the page
(:func:`records`: every frame drawn, with its camera and light, and every map made, as
:class:`web3d.headless.Records` read them) and interpreted per system (:class:`SystemStats`):

- frame times by phase: ``all`` (the pane's whole time per frame), ``idle`` (no map in flight at any time of the
  frame), ``in_flight`` (drawn while a map was being made: the frame that sent the request, after sending it, and
  the frames after it until the one it lands in; the request's own synchronous half, GIGAN's G-buffer pass and
  encoding, is left out: it is the map's ``gi_render``), ``landing`` (a map landed: decoded, bound, first warped);
- per map, the frames drawn while it was made (from its request's frame to the one before it landed);
- per frame, the age of the map it showed (since its view was captured), in ms and in frames;
- per frame that moved the camera or the light, the time to the first frame (it or a later one) showing a map
  within the GI tree's tolerance of its view (:func:`baseline_cloudbaking.client_run.perceived_latency`, the cloud
  clients' own measure; no such frame: censored), and whether it was in tolerance;
- per map, each stage's time and the total; the cloud's hit rate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

from gicore.camera import Camera
from gicore.path_file import FORMAT
from web3d.headless import Segment

GIGAN, CLOUD = "gigan", "cloud_baking"
#: The page's key of each system's statistics in a frame record.
PANES = {GIGAN: "gigan", CLOUD: "cloud"}
STAGES = {
    GIGAN: ("gi_render", "inference", "di", "warp", "blend"),
    CLOUD: ("transmission", "server", "decode", "di", "warp", "blend"),
}
PHASES = ("all", "idle", "in_flight", "landing")
#: What the page holds besides its frames and maps: its scene, renderer and runtime, the parity inputs of its first
#: GI map and both canvases' last frames.
READ_PAGE = "({scene: viewer.config.scene, info: viewer.info, parity: viewer.parity, snapshot: viewer.snapshot()})"


def session(scene: str, frames: list[dict[str, Any]]) -> dict[str, Any]:
    """The frames drawn as a path file (:mod:`gicore.path_file`): each one's camera and light, ``t_ms`` from the
    first's."""
    t0 = frames[0]["t"] if frames else 0.0
    views = [{"t_ms": f["t"] - t0, "camera": f["camera"], "light": f["light"]} for f in frames]
    return {"format": FORMAT, "scene": scene, "source": "drawn in gigan-web", "frames": views}


def records(page: Any) -> dict[str, Any]:
    """The page's records: every frame drawn and map made (``page.records``, read up to now), the session of
    the frames drawn (:func:`session`) and what :data:`READ_PAGE` reads."""
    page.records.pull(page)
    data = page.evaluate(READ_PAGE)
    scene, frames = data.pop("scene"), page.records.frames
    return data | {"frames": frames, "maps": page.records.maps, "session": session(scene, frames)}


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
    def of(cls, segment: Segment, frames: list[dict], maps: list[dict], recorded: list[dict]) -> Replayed:
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
    """The GI camera (``gi_fov``, n x n) at a recorded frame's view."""
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


def ages(run: Replayed, pane: str, key: str) -> list[float]:
    """Per frame of the replay that showed a map, its age (``key``: ``map_age_ms`` or ``map_age_frames``)."""
    return [f[pane][key] for f in run.frames if f[pane][key] is not None]


@dataclass(frozen=True)
class SystemStats:
    """One system's measures in one replay (module docstring): ``frames`` the frame that requested each of its
    maps; ``stages`` per stage and ``total``, each map's time (ms, in ``frames``' order); ``phases`` the frame times
    (ms) by phase; ``during`` per map, the frames drawn while it was made; ``age_ms`` and ``age_frames`` per frame
    that showed a map, its age; ``perceived`` :func:`perceived`'s rows; ``hit_rate`` (None: not cloud baking, or
    no maps)."""

    frames: list[int]
    stages: dict[str, list[float]]
    phases: dict[str, list[float]]
    during: dict[int, int]
    age_ms: list[float]
    age_frames: list[float]
    perceived: list[dict[str, Any]]
    hit_rate: float | None

    @classmethod
    def of(cls, run: Replayed, system: str, gi_fov: float, n: int, cell_size: float | None) -> SystemStats:
        """``system``'s measures in ``run``; ``gi_fov``, ``n`` and ``cell_size``: the scene's GI camera and light
        cell, for perceived latency."""
        pane = PANES[system]
        maps = [m for m in run.maps if m["system"] == system]
        stages = {s: [m["stages"][s] for m in maps] for s in STAGES[system]} | {"total": [m["total"] for m in maps]}
        hit_rate = sum(bool(m.get("hit")) for m in maps) / len(maps) if system == CLOUD and maps else None
        return cls(
            frames=[m["frame"] for m in maps],
            stages=stages,
            phases=phases(run, pane),
            during=frames_during(run, system),
            age_ms=ages(run, pane, "map_age_ms"),
            age_frames=ages(run, pane, "map_age_frames"),
            perceived=perceived(run, system, gi_fov, n, cell_size),
            hit_rate=hit_rate,
        )

    @property
    def served(self) -> list[float]:
        """Perceived latency (ms) of the moved frames a map of the replay served (the rest: censored)."""
        return [r["perceived_ms"] for r in self.perceived if r["perceived_ms"] != ""]
