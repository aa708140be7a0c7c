"""The per-frame client loop shared by both systems, its two protocols and the GI-map value
(docs/architecture.md, Client loop).

Each system brings a :class:`GISource` (GIGAN: the generator on DI + G-buffers rendered at the GI camera;
cloud baking: a server asked over HTTP in a background thread) and a :class:`Warp` (structure-aware or
pixel-level). :class:`ClientLoop` runs them frame by frame at the local camera: request a map every k frames
or when the view leaves the bound map's tolerance, take the newest map that has arrived (``gi_wait``), bind a
new one, render DI with the warp's pass and warp (``di``, the warp's stages), compose (``blend`` or
``residual``). Every frame gives a row of stage times, what it blocked on, what the bound map cost and its age
(:meth:`ClientLoop.columns`); :func:`run_frames` drives a loop along a camera path and scores frames against
the path-traced GT every ``gt_every`` frames, untimed.
"""

from __future__ import annotations

import csv
import io
import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np

from gicore import option_groups
from gicore.blend import COMPOSITIONS, blend, residual
from gicore.camera import Camera
from gicore.error_policy import UserError, writable_dir
from gicore.fileio import atomic_write_bytes
from gicore.metrics import lf_error, psnr, ssim
from gicore.options import FOV_DEGREES, FRAMES, check_fields
from gicore.paths import camera_path, frame_seed, light_position
from gicore.render_cache import RenderCache
from gicore.scene import SceneSpec
from gicore.timing import Stopwatch
from gicore.tonemap import tonemap

if TYPE_CHECKING:
    from gicore.render import Renderer

Light = tuple[float, float, float]
Timings = dict[str, float]
#: What a warp brings to the current view, per composition: the full GI map for eq. 1, its indirect
#: part for the residual composition (which adds it to the current DI).
LAYERS = {"blend": "radiance", "residual": "indirect"}
#: Renderers of a client's per-frame raster passes (:attr:`PathRunConfig.renderer`): OpenGL
#: (:class:`gicore.gl.GLRenderer`) or Mitsuba's centre-sampled passes (:class:`gicore.render.Renderer`).
RENDERERS = ("gl", "mitsuba")
#: Backends of a client's warp and composition (:attr:`PathRunConfig.warp_backend`): numpy on the passes read
#: back, or shaders on the GL renderer's textures (a :class:`FrameWarp`); auto picks per renderer.
WARP_BACKENDS = ("auto", "numpy", "gl")
#: The GL renderer's level of detail in both clients (``gicore.gl.GLRenderer(lod=...)``): per view, the coarsest
#: level whose calibrated G-buffer error stays within its bound, as a real-time client draws. On llvmpipe the
#: passes are vertex-bound, so full detail is no faster than Mitsuba; the bound costs the shipped model at most
#: 0.0003 SSIM against full detail (``gicore.gl.lod.LOD_BOUND``).
CLIENT_LOD = "auto"


# -- the GI map ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class GIMap:
    """A GI map at its GI ``camera`` (whose ``view()``/``proj()`` are the OpenGL matrices the warps use),
    with what warping and composition need, and when it was asked for and arrived.

    ``radiance``: linear GI, HxWxC (C = 3 for real maps); ``depth``: linear view depth at texel centres,
    HxW, 0 = background; ``di``: the direct illumination the map was made with at the same camera
    (HxWxC), or None when the source did not send it (then :attr:`indirect` is unavailable);
    ``frame``: the frame that requested it; ``requested_at`` / ``arrived_at``: ``time.perf_counter()``
    stamps; ``stages``: what producing it cost, ms per stage (the source's :attr:`GISource.stages`).
    """

    camera: Camera
    radiance: np.ndarray
    depth: np.ndarray
    di: np.ndarray | None = None
    frame: int = -1
    requested_at: float = 0.0
    arrived_at: float = 0.0
    stages: Timings = field(default_factory=dict)

    def __post_init__(self) -> None:
        shape = (self.camera.height, self.camera.width)
        if self.radiance.ndim != 3 or self.radiance.shape[:2] != shape or self.depth.shape != shape:
            raise ValueError(
                f"GI map {self.radiance.shape} and depth {self.depth.shape} must be {shape[0]}x{shape[1]}(xC)"
                " like the GI camera"
            )
        if self.di is not None and self.di.shape != self.radiance.shape:
            raise ValueError(f"the GI map's DI is {self.di.shape}, its radiance {self.radiance.shape}")

    @cached_property
    def indirect(self) -> np.ndarray:
        """The map's indirect light ``max(radiance - di, 0)`` (computed once, on first use)."""
        if self.di is None:
            raise ValueError(
                "this GI map carries no DI of its view, so its indirect part is unknown; ask the source for the DI too"
            )
        return np.maximum(self.radiance - self.di, 0.0)

    def layer(self, name: str) -> np.ndarray:
        """``"radiance"`` or ``"indirect"`` (see :data:`LAYERS`)."""
        if name not in ("radiance", "indirect"):
            raise ValueError(f"layer must be 'radiance' or 'indirect', got {name!r}")
        return self.radiance if name == "radiance" else self.indirect

    @property
    def latency_ms(self) -> float:
        """Request to arrival."""
        return (self.arrived_at - self.requested_at) * 1e3

    @classmethod
    def blank(cls, camera: Camera, channels: int = 3) -> GIMap:
        """An all-background map (zero radiance and depth): binds and warps like any map, so it warms up a
        warp's passes without a source."""
        zeros = np.zeros((camera.height, camera.width, channels), np.float32)
        return cls(camera, zeros, np.zeros(zeros.shape[:2], np.float32), zeros)


def texel_depth(renderer: Renderer, camera: Camera) -> np.ndarray:
    """A GI map's depth: linear view depth at texel centres from the centre-sampled pass (0 on background),
    so that warps unproject exact centre rays and a map warped to its own camera is the identity."""
    p = renderer.render_uv(camera)
    return np.where(p["mask"], camera.view_depth(p["position"]), 0.0).astype(np.float32)


# -- protocols ----------------------------------------------------------------------------------------------
class GISource(Protocol):
    """Makes GI maps at GI cameras on request.

    ``request`` starts making the map for ``frame`` at the GI ``camera`` under ``light`` and returns
    whether it did (False: the source is still busy with an earlier request, and nothing happened). A
    synchronous source finishes inside ``request``; a remote one works in a background thread.
    ``latest`` returns the newest map that has arrived (or None), at once. ``warm_up`` runs the source's
    passes once, untimed and without producing a map, so one-off compilation stays out of frame times.
    ``stages``: the names of the per-map costs its maps report (:attr:`GIMap.stages`).
    """

    name: str
    stages: tuple[str, ...]

    def request(self, camera: Camera, light: Light, frame: int) -> bool: ...

    def latest(self) -> GIMap | None: ...

    def warm_up(self, camera: Camera, light: Light) -> None: ...


class Warp(Protocol):
    """Brings a bound GI map to other views.

    ``bind(gi)``: the per-map work (returns its timings, stage ``bind``); ``warp(camera, di, passes)``: the
    map's ``layer`` at ``camera``, complete (fallback or hole filling applied), as (HxWxC image, HxW valid
    mask, stage timings); ``valid`` is False where the GI came from the fallback or hole filling, True where
    it came from the map and on background (nothing to warp). ``di`` is the current frame's DI at ``camera``
    (a fallback may use it) and ``passes`` the warp's ``raster`` pass (:data:`gicore.buffers.RASTERS`, None:
    it reads none) rendered with it after ``bind`` (``render_di_raster``: one geometry pass on a GL
    renderer). ``stages``: every stage name ``bind`` and ``warp`` report.
    """

    name: str
    layer: str
    raster: str | None
    stages: tuple[str, ...]

    def bind(self, gi: GIMap) -> Timings: ...

    def warp(
        self, camera: Camera, di: np.ndarray, passes: dict[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, Timings]: ...


@runtime_checkable
class FrameWarp(Protocol):
    """A warp whose frames are drawn, warped and composed in the GL renderer's context (``gicore.gl.frame``):
    :class:`Warp`'s attributes and ``bind``, and in place of ``warp``, ``frame(camera, light, composition,
    tau)``: a whole frame with a map bound, as (HxWx3 image, HxW valid mask, ms of ``di``, its per-frame
    ``stages`` and ``compose``); only the image and the mask are read back."""

    name: str
    layer: str
    raster: str | None
    stages: tuple[str, ...]

    def bind(self, gi: GIMap) -> Timings: ...

    def frame(
        self, camera: Camera, light: Light, composition: str, tau: float
    ) -> tuple[np.ndarray, np.ndarray, Timings]: ...


def warp_view(
    warp: Warp, renderer: Renderer, camera: Camera, light: Light, seed: int = 0
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

    def latest(self) -> GIMap | None:
        return self._latest

    def warm_up(self, camera: Camera, light: Light) -> None:
        self.produce(camera, light, -1)


class PasteWarp:
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
        if self.gi_fov is not None and not 0.0 < self.gi_fov < 180.0:
            raise ValueError(f"gi_fov must lie strictly between 0 and 180 degrees, got {self.gi_fov}")
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
TAIL_COLUMNS = ("frame_ms", "ssim", "psnr", "lf_error")
#: The quality columns of a frame that is not scored against GT (:data:`TAIL_COLUMNS` after ``frame_ms``).
UNSCORED = dict.fromkeys(TAIL_COLUMNS[1:], "")


@dataclass(frozen=True)
class PathRunConfig:
    """What every client run (``gigan-client``, ``cloudbaking-client``) shares: the scene, the camera path
    both clients fly (the scene's fly-through, or a ``--path`` file: :func:`gicore.path_file.flown_path`), the GI
    period, composition and GT scoring. ``None`` FOVs come from the scene spec
    (local 60°, GI 90°). Each system's config adds its own GI source and warp fields.

    Both clients' command lines are derived from these fields (:mod:`gicore.options`): each option, its
    default, its limits and its help are declared here once; building the config checks the same limits
    (``ValueError`` naming the option)."""

    scene: str = option_groups.scene()
    #: Frames to run.
    frames: int = field(default=60, metadata=FRAMES)
    resolution: int = option_groups.resolution(note="of every render and GI map")
    every: int = option_groups.every(note="Table 3's inference frequency")
    #: GI-camera FOV in degrees; absent: the scene's (90).
    gi_fov: float | None = field(default=None, metadata=FOV_DEGREES)
    #: Local-camera FOV in degrees; absent: the scene's (60).
    local_fov: float | None = field(default=None, metadata=FOV_DEGREES)
    orbit_frames: int = option_groups.orbit_frames()
    path: Path | None = option_groups.path()
    #: Eq. 1 weight of DI in the blend (0: the GI map alone, which already holds direct light).
    tau: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})
    #: Composition: blend (eq. 1) or residual (current DI + warped indirect light).
    composition: Literal[COMPOSITIONS] = "blend"  # type: ignore[valid-type]
    spp: int = option_groups.spp(note="of the GT renders and the cloud server's maps")
    denoise: bool = option_groups.denoise()
    #: Compare the composed frame with the path-traced GT every N frames (0: never).
    gt_every: int = field(default=0, metadata={"min": 0})
    seed: int = option_groups.seed(note="the camera path and the renders' noise")
    #: Folder of path-traced GT frames shared between runs (keyed by scene spec, camera, light, spp, denoise, seed
    #: and frame; :mod:`gicore.render_cache`); absent: every run path-traces its own.
    gt_cache: Path | None = None
    #: Renderer of the per-frame raster passes (GIGAN's DI + G-buffers at the GI camera, each shown frame's DI
    #: with its warp's uv or mask pass): gl (OpenGL on headless EGL at level of detail auto; without a context: one
    #: warning and mitsuba) or mitsuba. Path tracing (GT, the gt source, the server) is always Mitsuba's. The
    #: shipped model scores within 0.005 SSIM of Mitsuba inputs on GL inputs at lod auto (-0.0009 to +0.0026 on
    #: the five scenes, bench quality --renderers gl,mitsuba; see the model card).
    renderer: Literal[RENDERERS] = "gl"  # type: ignore[valid-type]
    #: Backend of the warp and the composition: numpy (on the passes read back), gl (shaders on the GL renderer's
    #: textures, only the composed frame read back; needs --renderer gl) or auto (gl where the GL renderer runs on
    #: a GPU; numpy on a CPU rasteriser such as llvmpipe, where numpy is as fast: docs/architecture.md, OpenGL
    #: passes).
    warp_backend: Literal[WARP_BACKENDS] = "auto"  # type: ignore[valid-type]

    def __post_init__(self) -> None:
        try:
            check_fields(self)
        except UserError as err:
            raise ValueError(str(err)) from None
        if self.warp_backend == "gl" and self.renderer != "gl":
            raise ValueError("--warp-backend gl runs on the GL renderer's textures: pass --renderer gl")

    def check_gt_cache(self) -> None:
        """Refuse a ``--gt-cache`` that is a file or cannot be made a folder, before any frame is path-traced."""
        if self.gt_cache is not None:
            writable_dir(self.gt_cache, name="--gt-cache")

    def local_fov_of(self, spec: SceneSpec) -> float:
        """The local camera's FOV: the given one, else the scene's (zero is not absent)."""
        return spec.camera.local_fov if self.local_fov is None else self.local_fov

    def gi_fov_of(self, spec: SceneSpec) -> float:
        """The GI camera's FOV: the given one, else the scene's."""
        return spec.camera.gi_fov if self.gi_fov is None else self.gi_fov

    def as_json(self) -> dict[str, Any]:
        """The fields as JSON data (paths as strings), for a run's summary."""
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(self).items()}

    def ground_truth(self, renderer: Renderer, spec: SceneSpec) -> GroundTruth:
        """The run's GT scorer (every ``gt_every`` frames, through ``gt_cache`` when given)."""
        store = RenderCache(self.gt_cache, spec) if self.gt_cache is not None else None
        return GroundTruth(renderer, self.gt_every, self.spp, self.denoise, self.seed, store=store)


def open_raster(
    choice: str, path_renderer: Renderer, open_gl: Callable[[], Any], unavailable: type[Exception]
) -> tuple[Any, str]:
    """The renderer of a client's per-frame raster passes for ``choice`` (:data:`RENDERERS`), and the name
    of the one that will run them.

    ``"mitsuba"`` is ``path_renderer`` itself. ``"gl"`` is ``open_gl()`` (the client's
    :class:`gicore.gl.GLRenderer` of the same scene and resolution; passed in, as ``gicore.gl`` imports this
    module); when it raises ``unavailable`` (:class:`gicore.gl.RasterUnavailable`: no GL context opens) the
    run falls back to ``path_renderer`` after one line on stderr naming the reason: not an error, but the
    name returned says what ran, for the run's summary.
    """
    if choice not in RENDERERS:
        raise ValueError(f"renderer must be one of {RENDERERS}, got {choice!r}")
    if choice == "mitsuba":
        return path_renderer, "mitsuba"
    try:
        return open_gl(), "gl"
    except unavailable as err:
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    print(f"warning: renderer gl is unavailable, using mitsuba: {reason}", file=sys.stderr, flush=True)
    return path_renderer, "mitsuba"


@dataclass
class FrameResult:
    """One composed frame (linear radiance, HxWx3) and its row."""

    image: np.ndarray
    row: dict[str, Any]


def _turn_deg(a: Camera, b: Camera) -> float:
    da = np.subtract(a.target, a.origin)
    db = np.subtract(b.target, b.origin)
    cos = float(np.dot(da, db) / (np.linalg.norm(da) * np.linalg.norm(db)))
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


class ClientLoop:
    """One client: DI renders on ``renderer``, GI maps from ``source``, brought to each view by ``warp``
    (see the module docstring). :meth:`step` runs one frame."""

    def __init__(self, cfg: LoopConfig, renderer: Renderer, source: GISource, warp: Warp | FrameWarp):
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
        self._no_indirect: np.ndarray | None = None
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
        if isinstance(self.warp, FrameWarp):
            self.warp.frame(camera, light, self.cfg.composition, self.cfg.tau)
        else:
            self.warp.warp(camera, *self.renderer.render_di_raster(camera, light, self.warp.raster))
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
        gi = self.source.latest()
        deadline = time.perf_counter() + self.cfg.first_map_timeout_s
        while gi is None and self.bound is None and not self._first_map_waited_out and time.perf_counter() < deadline:
            time.sleep(0.0005)
            gi = self.source.latest()
        self._first_map_waited_out |= gi is None and self.bound is None
        return gi

    def step(self, frame: int, camera: Camera, light: Light) -> FrameResult:
        """(Maybe) ask for and bind a new GI map, render, warp, compose one frame at the local ``camera``.

        The frame's DI and its warp's raster pass are one render (stage ``di``) after binding, since the
        structure-aware warp's pass interpolates the bound map's coordinates."""
        cfg = self.cfg
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
        if self.bound is not None and isinstance(self.warp, FrameWarp):  # drawn, warped and composed in GL
            image, valid, timings = self.warp.frame(camera, light, cfg.composition, cfg.tau)
            sw.ms |= timings
        else:
            image, valid = self._render_and_compose(frame, camera, light, sw)
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
        return FrameResult(image, {c: row.get(c, "") for c in columns if c not in TAIL_COLUMNS[1:]})

    def _render_and_compose(self, frame: int, camera: Camera, light: Light, sw: Stopwatch) -> tuple[np.ndarray, ...]:
        """The frame's DI and its warp's pass read back (stage ``di``), the warp's stages, then the composition
        (``compose``): (image, valid mask); before any map the frame is its DI alone."""
        cfg = self.cfg
        raster = None if self.bound is None else self.warp.raster
        di, passes = self.renderer.render_di_raster(camera, light, raster, seed=frame_seed(cfg.seed, "di", frame))
        sw.lap("di")
        if self.bound is None:  # no map has arrived: the frame is its DI alone
            image, valid = di, np.zeros(di.shape[:2], dtype=bool)
        else:
            warped, valid, timings = self.warp.warp(camera, di, passes)
            sw.ms |= timings
            sw.restart()
            if cfg.composition == "blend":
                image = blend(di, warped, cfg.tau)
            else:  # the warped layer is already indirect-only, so nothing is subtracted from it
                if self._no_indirect is None or self._no_indirect.shape != di.shape:
                    self._no_indirect = np.zeros_like(di)
                image = residual(di, warped, self._no_indirect)
        sw.lap("compose")
        return image, valid


# -- driving a loop along a path, scoring against GT ------------------------------------------------------
def path_views(
    spec: SceneSpec, frames: int, orbit_frames: int, seed: int, fov: float, resolution: int
) -> list[tuple[Camera, Light]]:
    """(local camera, light) of each frame: the scene's fly-through with ``orbit_frames`` frames per orbit
    (repeating), FOV ``fov``, and the light's schedule."""
    cams = camera_path(spec, orbit_frames, seed=seed, fov=fov, resolution=resolution)
    return [(cams[f % orbit_frames], light_position(spec, f)) for f in range(frames)]


def render_gt(
    renderer: Renderer, camera: Camera, light: Light | None, spp: int, seed: int, denoise: bool
) -> np.ndarray:
    """Path-traced GT at ``camera``, OIDN-denoised (albedo/normal guided) when asked."""
    gt = renderer.render_gt(camera, light, spp=spp, seed=seed)
    return renderer.denoise(gt, renderer.render_gbuffers(camera, seed=seed)) if denoise else gt


@dataclass
class GroundTruth:
    """Scores composed frames against the path-traced GT at the local camera, every ``every`` frames.

    ``cache`` (optional, shared between runs of a bench in one process) keeps GT renders by (camera, light,
    spp, denoise, seed, frame); ``store`` (optional) keeps them on disk for other processes (a bench's client
    runs along one path). Neither's renders are part of any stage time.
    """

    renderer: Renderer
    every: int
    spp: int = 64
    denoise: bool = True
    seed: int = 0
    cache: dict | None = None
    store: RenderCache | None = None

    def __post_init__(self) -> None:
        if self.every < 1 or self.spp < 1:
            raise ValueError(f"GT every and spp must be >= 1, got {self.every} and {self.spp}")

    def reference(self, frame: int, camera: Camera, light: Light) -> np.ndarray:
        key = ("gt", camera, tuple(light), self.spp, self.denoise, self.seed, frame)
        if self.cache is not None and key in self.cache:
            return self.cache[key]

        def render() -> np.ndarray:
            return render_gt(self.renderer, camera, light, self.spp, frame_seed(self.seed, "gt", frame), self.denoise)

        gt = self.store.fetch(key, lambda: {"gt": render()})["gt"] if self.store is not None else render()
        if self.cache is not None:
            self.cache[key] = gt
        return gt

    def score(self, frame: int, camera: Camera, light: Light, image: np.ndarray) -> dict[str, float | str]:
        """SSIM, PSNR and low-frequency error (tone-mapped; PSNR may be inf) on scored frames, ``""`` on the others."""
        if frame % self.every:
            return dict(UNSCORED)
        return evaluate(image, self.reference(frame, camera, light))


def evaluate(image: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """SSIM, PSNR and low-frequency error (:func:`gicore.metrics.lf_error`) of a composed frame against the
    GT, both tone-mapped (PSNR may be inf)."""
    a, b = tonemap(image), tonemap(gt)
    return {"ssim": ssim(a, b), "psnr": psnr(a, b), "lf_error": lf_error(a, b)}


def run_frames(
    loop: ClientLoop,
    views: Sequence[tuple[Camera, Light]],
    ground_truth: GroundTruth | None = None,
    on_frame: Callable[[int, FrameResult], None] | None = None,
) -> list[dict[str, Any]]:
    """Warm ``loop`` up at the first view, then run one frame per view; returns the rows (scored by
    ``ground_truth`` where given). ``on_frame(frame, result)`` sees every composed frame."""
    loop.warm_up(*views[0])
    rows = []
    for frame, (camera, light) in enumerate(views):
        result = loop.step(frame, camera, light)
        result.row |= ground_truth.score(frame, camera, light, result.image) if ground_truth else dict(UNSCORED)
        rows.append(result.row)
        if on_frame is not None:
            on_frame(frame, result)
    return rows


# -- summaries ----------------------------------------------------------------------------------------------
def _values(rows: Iterable[dict[str, Any]], column: str) -> list[float]:
    return [float(r[column]) for r in rows if r.get(column, "") != ""]


def amortized_fps(rows: list[dict[str, Any]], every: int) -> dict[str, float]:
    """Frame rate with the GI-map cost spread over its ``every`` frames.

    ``local_ms``: median per-frame work other than waiting for and binding maps; ``gi_ms``: mean cost of
    one map (producing it, :attr:`GIMap.stages`, plus binding it); ``fps = 1000 / (local_ms + gi_ms /
    every)``.
    """
    local = [float(r["frame_ms"]) - float(r["gi_wait_ms"]) - float(r.get("bind_ms") or 0.0) for r in rows]
    per_map = [float(r["gi_ms"]) + float(r.get("bind_ms") or 0.0) for r in rows if r["gi_new"]]
    local_ms = float(np.median(local))
    gi_ms = float(np.mean(per_map)) if per_map else 0.0
    return {"local_ms": local_ms, "gi_ms": gi_ms, "fps": 1000.0 / (local_ms + gi_ms / every)}


def summarize(rows: list[dict[str, Any]], every: int) -> dict[str, Any]:
    """Amortised fps, median of every ``*_ms`` column and of the map's age, mean quality (SSIM, PSNR,
    low-frequency error) of scored frames."""
    out: dict[str, Any] = amortized_fps(rows, every)
    columns = [c for c in rows[0] if c.endswith("_ms")] + ["gi_age_frames"]
    out["median"] = {c: float(np.median(v)) for c in columns if (v := _values(rows, c))}
    out["mean_valid_frac"] = float(np.mean(_values(rows, "valid_frac")))
    ssims = _values(rows, "ssim")
    if ssims:
        out["mean_ssim"] = float(np.mean(ssims))
        finite = [p for p in _values(rows, "psnr") if math.isfinite(p)]
        out["mean_psnr"] = float(np.mean(finite)) if finite else math.inf
        out["mean_lf_error"] = float(np.mean(_values(rows, "lf_error")))
    return out


def write_rows(rows: list[dict[str, Any]], path: Path) -> Path:
    """The per-frame rows as CSV (columns in the rows' order), written atomically."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_bytes(path, buffer.getvalue().encode())
