"""The per-frame client loop shared by both systems and its two protocols (docs/architecture.md, Client loop).

Each system brings a :class:`GISource` (GIGAN: the generator on DI + G-buffers rendered at the GI camera;
cloud baking: a server asked over HTTP in a background thread) and a :class:`Warp` (structure-aware or
pixel-level) of :class:`gicore.gi_map.GIMap` values. :class:`ClientLoop` runs them frame by frame at the local
camera: request a map every k frames or when the view leaves the bound map's tolerance, take the newest map
that has arrived (``gi_wait``), bind a new one, render DI with the warp's pass and warp (``di``, the warp's
stages), compose (``blend`` or ``residual``). Every frame gives a row of stage times, what it blocked on, what
the bound map cost and its age (:meth:`ClientLoop.columns`); :func:`run_frames` drives a loop along a camera
path and scores frames against the path-traced GT every ``gt_every`` frames, untimed
(:mod:`gicore.ground_truth`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from gicore.blend import COMPOSITIONS, blend, residual
from gicore.camera import FOV_MIN, Camera
from gicore.gi_map import LAYERS, GIMap, Timings
from gicore.ground_truth import QUALITY_COLUMNS, UNSCORED
from gicore.paths import Light, frame_seed
from gicore.timing import Stopwatch

if TYPE_CHECKING:
    from gicore.ground_truth import GroundTruth
    from gicore.render import Renderer


# -- protocols ----------------------------------------------------------------------------------------------
class GISource(Protocol):
    """Makes GI maps at GI cameras on request.

    ``request`` starts making the map for ``frame`` at the GI ``camera`` under ``light`` and returns
    whether it did (False: the source is still busy with an earlier request, and nothing happened). A
    synchronous source finishes inside ``request``; a remote one works in a background thread.
    ``latest`` returns the newest map that has arrived (or None), at once, or waiting up to ``wait_s`` seconds for
    one while none has arrived and one is on its way. ``warm_up`` runs the source's
    passes once, untimed and without producing a map, so one-off compilation stays out of frame times.
    ``stages``: the names of the per-map costs its maps report (:attr:`GIMap.stages`).
    """

    name: str
    stages: tuple[str, ...]

    def request(self, camera: Camera, light: Light, frame: int) -> bool: ...

    def latest(self, wait_s: float = 0.0) -> GIMap | None: ...

    def warm_up(self, camera: Camera, light: Light) -> None: ...


class Warp(Protocol):
    """Brings a bound GI map to other views and composes the frame.

    ``bind(gi)``: the per-map work (returns its timings, stage ``bind``). ``frame(renderer, camera, light,
    composition, tau, seed)``: one whole frame with a map bound, as (HxWx3 linear image, HxW valid mask, ms of
    ``di``, the warp's per-frame stages and ``compose``): the frame's DI and the warp's ``raster`` pass
    (:data:`gicore.buffers.RASTERS`, None: it reads none) rendered on ``renderer`` (``seed``: the DI's draw), the
    bound map's ``layer`` warped to ``camera`` (fallback or hole filling applied), composed with the DI. ``valid``
    is False where the GI came from the fallback or hole filling, True where it came from the map and on
    background (nothing to warp). :class:`HostWarp` does this on the host with numpy; ``gicore.gl.frame``'s
    ``ShaderWarp`` in the GL renderer's context. ``stages``: every stage name ``bind`` and ``frame`` report.
    """

    name: str
    layer: str
    raster: str | None
    stages: tuple[str, ...]

    def bind(self, gi: GIMap) -> Timings: ...

    def frame(
        self, renderer: Renderer, camera: Camera, light: Light, composition: str, tau: float, seed: int
    ) -> tuple[np.ndarray, np.ndarray, Timings]: ...


class HostWarp:
    """Base of the warps whose per-frame work runs on the host: subclasses implement ``bind`` and :meth:`warp`;
    :meth:`frame` renders the DI with the warp's pass, warps and composes with numpy."""

    name: str
    layer: str
    raster: str | None
    stages: tuple[str, ...]
    _no_indirect: np.ndarray | None = None  # the residual's zero "indirect of the DI", kept between frames

    def bind(self, gi: GIMap) -> Timings:
        raise NotImplementedError

    def warp(
        self, camera: Camera, di: np.ndarray, passes: dict[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, Timings]:
        """The bound map's layer at ``camera``, complete, as (HxWxC image, HxW valid mask, stage timings); ``di``
        is the current frame's DI at ``camera`` (a fallback may use it), ``passes`` the warp's raster pass."""
        raise NotImplementedError

    def frame(
        self, renderer: Renderer, camera: Camera, light: Light, composition: str, tau: float, seed: int
    ) -> tuple[np.ndarray, np.ndarray, Timings]:
        sw = Stopwatch()
        di, passes = renderer.render_di_raster(camera, light, self.raster, seed=seed)
        sw.lap("di")
        warped, valid, timings = self.warp(camera, di, passes)
        sw.ms |= timings
        sw.restart()
        if composition == "blend":
            image = blend(di, warped, tau)
        else:  # the warped layer is already indirect-only, so nothing is subtracted from it
            if self._no_indirect is None or self._no_indirect.shape != di.shape:
                self._no_indirect = np.zeros_like(di)
            image = residual(di, warped, self._no_indirect)
        sw.lap("compose")
        return image, valid, sw.ms


def warp_view(
    warp: HostWarp, renderer: Renderer, camera: Camera, light: Light, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bound map brought to ``camera`` as a client frame does it: (DI, warped layer, valid mask), the DI and
    the warp's raster pass rendered together on ``renderer``."""
    di, passes = renderer.render_di_raster(camera, light, warp.raster, seed=seed)
    image, valid, _ = warp.warp(camera, di, passes)
    return di, image, valid


class SynchronousSource:
    """Base of sources that make their map inside :meth:`request` (the ONNX generator, the GT stand-in):
    subclasses implement :meth:`produce`; the map's stamps are set here."""

    name: str = "synchronous"
    stages: tuple[str, ...] = ()

    def __init__(self) -> None:
        self._latest: GIMap | None = None

    def produce(self, camera: Camera, light: Light, frame: int) -> GIMap:
        """The map for ``frame`` (its stamps are ignored); ``frame`` -1 is the warm-up."""
        raise NotImplementedError

    def request(self, camera: Camera, light: Light, frame: int) -> bool:
        t0 = time.perf_counter()
        gi = self.produce(camera, light, frame)
        self._latest = replace(gi, frame=frame, requested_at=t0, arrived_at=time.perf_counter())
        return True

    def latest(self, wait_s: float = 0.0) -> GIMap | None:
        return self._latest  # made inside request(): there is nothing to wait for

    def warm_up(self, camera: Camera, light: Light) -> None:
        self.produce(camera, light, -1)


class PasteWarp(HostWarp):
    """No warping: the bound map's layer is used as it is, so it must be made with the local camera's FOV
    (the paper's baseline without warping)."""

    name = "none"
    raster = None
    stages = ("bind",)

    def __init__(self, layer: str = "radiance") -> None:
        self.layer = layer
        self._image: np.ndarray | None = None

    def bind(self, gi: GIMap) -> Timings:
        sw = Stopwatch()
        self._image = gi.layer(self.layer)
        sw.lap("bind")
        return sw.ms

    def warp(
        self, camera: Camera, di: np.ndarray, passes: dict[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, Timings]:
        if self._image is None:
            raise RuntimeError("no GI map is bound; call bind() first")
        if self._image.shape[:2] != (camera.height, camera.width):
            raise ValueError(f"the bound map is {self._image.shape[:2]}, the camera {camera.height}x{camera.width}")
        return self._image, np.ones(self._image.shape[:2], dtype=bool), {}


# -- the loop -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LoopConfig:
    """How one client loop asks for GI maps and composes frames."""

    #: GI-map period k: ask for a new map when the bound one was requested this many frames ago.
    every: int = 30
    #: GI-camera FOV F_GI in degrees; None: the local camera's FOV (what ``PasteWarp`` needs).
    gi_fov: float | None = None
    #: Also ask when the local camera is farther than this from the bound map's GI camera (scene units;
    #: None: never) ...
    max_move: float | None = None
    #: ... or its view direction has turned more than this many degrees from the GI camera's (None: never).
    max_turn: float | None = None
    #: Composition: ``blend`` (eq. 1) or ``residual`` (current DI + warped indirect light).
    composition: str = "blend"
    #: Eq. 1 weight of the DI (``blend`` only).
    tau: float = 0.0
    #: Seeds the per-frame DI renders (``frame_seed(seed, "di", frame)``).
    seed: int = 0
    #: Longest the run waits for its first map (s, once); past it, frames show the DI alone until a map arrives.
    first_map_timeout_s: float = 30.0

    def __post_init__(self) -> None:
        if self.every < 1:
            raise ValueError(f"every (k) must be >= 1, got {self.every}")
        if self.gi_fov is not None and not FOV_MIN <= self.gi_fov < 180.0:
            raise ValueError(f"gi_fov must be at least {FOV_MIN:g} and below 180 degrees, got {self.gi_fov}")
        for name in ("max_move", "max_turn"):
            value = getattr(self, name)
            if value is not None and not value > 0.0:
                raise ValueError(f"{name} must be > 0 (or None: never), got {value}")
        if self.composition not in COMPOSITIONS:
            raise ValueError(f"composition must be one of {COMPOSITIONS}, got {self.composition!r}")
        if not 0.0 <= self.tau <= 1.0:
            raise ValueError(f"tau must lie in [0, 1], got {self.tau}")
        if not self.first_map_timeout_s >= 0.0:
            raise ValueError(f"first_map_timeout_s must be >= 0, got {self.first_map_timeout_s}")


#: Row columns before the stage times, and after them.
HEAD_COLUMNS = (
    "frame",
    "gi_requested",
    "gi_new",
    "gi_age_frames",
    "gi_age_ms",
    "gi_latency_ms",
    "gi_wait_ms",
    "gi_ms",
    "valid_frac",
)
TAIL_COLUMNS = ("frame_ms", *QUALITY_COLUMNS)


@dataclass
class FrameResult:
    """One composed frame (linear radiance, HxWx3), its row, and when it started (``time.perf_counter``: its
    camera moved)."""

    image: np.ndarray
    row: dict[str, Any]
    started: float


def _turn_deg(a: Camera, b: Camera) -> float:
    da = np.subtract(a.target, a.origin)
    db = np.subtract(b.target, b.origin)
    cos = float(np.dot(da, db) / (np.linalg.norm(da) * np.linalg.norm(db)))
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


class ClientLoop:
    """One client: DI renders on ``renderer``, GI maps from ``source``, brought to each view by ``warp``
    (see the module docstring). :meth:`step` runs one frame."""

    def __init__(self, cfg: LoopConfig, renderer: Renderer, source: GISource, warp: Warp):
        if warp.layer != LAYERS[cfg.composition]:
            raise ValueError(
                f"the {cfg.composition} composition needs a warp of the {LAYERS[cfg.composition]!r} layer,"
                f" got {warp.layer!r}"
            )
        self.cfg = cfg
        self.renderer = renderer
        self.source = source
        self.warp = warp
        self.bound: GIMap | None = None
        self._first_map_waited_out = False  # the first map did not come in time: later frames do not wait

    def columns(self) -> tuple[str, ...]:
        """The row columns: :data:`HEAD_COLUMNS`, ``<stage>_ms`` for every stage, :data:`TAIL_COLUMNS`."""
        stages = dict.fromkeys(("di", *self.source.stages, *self.warp.stages, "compose"))
        return (*HEAD_COLUMNS, *(f"{s}_ms" for s in stages), *TAIL_COLUMNS)

    def gi_camera(self, camera: Camera) -> Camera:
        return camera if self.cfg.gi_fov is None else camera.with_fov(self.cfg.gi_fov)

    def warm_up(self, camera: Camera, light: Light) -> None:
        """Run every pass once, untimed (Mitsuba JIT-compiles each pass on first use), and forget the map."""
        self.source.warm_up(self.gi_camera(camera), light)
        self.renderer.render_di_raster(camera, light)  # a frame before any map: DI alone
        self.warp.bind(GIMap.blank(self.gi_camera(camera)))
        self.warp.frame(self.renderer, camera, light, self.cfg.composition, self.cfg.tau, 0)
        self.bound = None

    def _wants_map(self, frame: int, camera: Camera) -> bool:
        gi, cfg = self.bound, self.cfg
        if gi is None or frame - gi.frame >= cfg.every:
            return True
        if (
            cfg.max_move is not None
            and float(np.linalg.norm(np.subtract(camera.origin, gi.camera.origin))) > cfg.max_move
        ):
            return True
        return cfg.max_turn is not None and _turn_deg(camera, gi.camera) > cfg.max_turn

    def _newest(self) -> GIMap | None:
        """The newest arrived map; with none bound yet, wait for the first one (up to the timeout)."""
        first = self.bound is None and not self._first_map_waited_out
        gi = self.source.latest(self.cfg.first_map_timeout_s if first else 0.0)
        self._first_map_waited_out |= gi is None and self.bound is None
        return gi

    def step(self, frame: int, camera: Camera, light: Light) -> FrameResult:
        """(Maybe) ask for and bind a new GI map, render, warp, compose one frame at the local ``camera``.

        The frame's DI and its warp's raster pass are one render (stage ``di``) after binding, since the
        structure-aware warp's pass interpolates the bound map's coordinates."""
        cfg = self.cfg
        started = time.perf_counter()
        sw = Stopwatch()
        requested = self._wants_map(frame, camera) and self.source.request(self.gi_camera(camera), light, frame)
        gi = self._newest()
        sw.lap("gi_wait")
        row: dict[str, Any] = {
            "frame": frame,
            "gi_requested": int(requested),
            "gi_new": int(gi is not None and gi is not self.bound),
        }
        if row["gi_new"]:
            sw.ms |= self.warp.bind(gi)
            row["gi_ms"] = sum(gi.stages.values())
            row |= {f"{s}_ms": ms for s, ms in gi.stages.items()}
            self.bound = gi
        sw.restart()
        seed = frame_seed(cfg.seed, "di", frame)
        if self.bound is None:  # no map has arrived: the frame is its DI alone
            image = self.renderer.render_di_raster(camera, light, None, seed=seed)[0]
            valid = np.zeros(image.shape[:2], dtype=bool)
            sw.lap("di")
            sw.lap("compose")
        else:
            image, valid, timings = self.warp.frame(self.renderer, camera, light, cfg.composition, cfg.tau, seed)
            sw.ms |= timings
        gi = self.bound
        if gi is not None:
            row |= {
                "gi_age_frames": frame - gi.frame,
                "gi_age_ms": (time.perf_counter() - gi.requested_at) * 1e3,
                "gi_latency_ms": gi.latency_ms,
            }
        row |= {f"{s}_ms": ms for s, ms in sw.ms.items() if s != "gi_wait"}
        row |= {"gi_wait_ms": sw.ms["gi_wait"], "valid_frac": float(valid.mean()), "frame_ms": sum(sw.ms.values())}
        columns = self.columns()
        unknown = set(row) - set(columns)
        if unknown:  # a source or warp reported a stage it does not declare in its ``stages``
            raise RuntimeError(f"undeclared stage columns {sorted(unknown)}; add them to the source's or warp's stages")
        return FrameResult(image, {c: row.get(c, "") for c in columns if c not in QUALITY_COLUMNS}, started)


# -- driving a loop along a path -------------------------------------------------------------------------
def run_frames(
    loop: ClientLoop,
    views: Sequence[tuple[Camera, Light]],
    ground_truth: GroundTruth | None = None,
    on_frame: Callable[[int, FrameResult], None] | None = None,
    frame_rate: float | None = None,
) -> list[dict[str, Any]]:
    """Warm ``loop`` up at the first view, then run one frame per view; returns the rows (scored by
    ``ground_truth`` where given). ``on_frame(frame, result)`` sees every composed frame. ``frame_rate``: frames
    start no faster than this many per second, each on the first refresh of a display after the previous one's
    start (None: each as soon as the previous one is composed)."""
    loop.warm_up(*views[0])
    rows = []
    for frame, (camera, light) in enumerate(views):
        result = loop.step(frame, camera, light)
        result.row |= ground_truth.score(frame, camera, light, result.image) if ground_truth else dict(UNSCORED)
        rows.append(result.row)
        if on_frame is not None:
            on_frame(frame, result)
        if frame_rate:
            time.sleep(max(0.0, result.started + 1.0 / frame_rate - time.perf_counter()))
    return rows
