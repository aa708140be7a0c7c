"""What every client run shares (docs/architecture.md, Client loop): :class:`PathRunConfig` (the scene, the
camera path, the GI period, composition, GT scoring, the renderer and warp backend) and
:func:`open_raster`, which opens the renderer of a run's per-frame raster passes.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from gicore import option_groups
from gicore.blend import COMPOSITIONS
from gicore.error_policy import UserError, writable_dir
from gicore.ground_truth import GroundTruth
from gicore.options import FOV_DEGREES, FRAMES, check_fields
from gicore.render_cache import RenderCache
from gicore.scene import SceneSpec

if TYPE_CHECKING:
    from gicore.render import Renderer

#: Renderers of a client's per-frame raster passes (:attr:`PathRunConfig.renderer`): OpenGL
#: (:class:`gicore.gl.GLRenderer`) or Mitsuba's centre-sampled passes (:class:`gicore.render.Renderer`).
RENDERERS = ("gl", "mitsuba")
#: Backends of a client's warp and composition (:attr:`PathRunConfig.warp_backend`): numpy on the passes read
#: back, or shaders on the GL renderer's textures (``gicore.gl.frame.ShaderWarp``); auto picks per renderer.
WARP_BACKENDS = ("auto", "numpy", "gl")
#: The GL renderer's level of detail in both clients (``gicore.gl.GLRenderer(lod=...)``): per view, the coarsest
#: level whose calibrated G-buffer error stays within its bound, as a real-time client draws. On llvmpipe the
#: passes are vertex-bound, so full detail is no faster than Mitsuba; the bound costs the shipped model at most
#: 0.0003 SSIM against full detail (``gicore.gl.lod.LOD_BOUND``).
CLIENT_LOD = "auto"


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
    #: Frames per second the frames are paced to, as a display refreshes (absent: as fast as they render). Pace
    #: both clients alike when comparing them: an unpaced client's frame loop leaves its other work less time.
    frame_rate: float | None = field(default=None, metadata={"min": 1.0, "max": 1000.0})

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
