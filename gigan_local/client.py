"""The GIGAN client loop (paper III, Fig. 1; SPEC §5).

Along a scene's camera path, every frame the client

1. renders direct illumination (DI) at the local camera (FOV 60°);
2. every ``k`` frames obtains a GI map at the GI camera -- same position and orientation as the local
   camera at that frame, FOV ``F_GI`` (default 90°) -- from the ONNX generator (DI + G-buffers rendered
   at the GI camera, :class:`gigan_local.inference.GIModel`) or from the path-traced GT GI map rendered
   there (``gt``: an oracle stand-in for a perfect model, so the loop runs without a trained model);
3. warps the newest GI map (its indirect part for the residual composition) to the current view:
   structure-aware (:mod:`gigan_local.warp`), pixel-level (:mod:`baseline_cloudbaking.warp`), or not at
   all (``none``: the map is pasted as is, so it is generated with the local camera's FOV);
4. composes: eq. 1 (``blend``, ``tau``) or ``residual`` (current DI + warped indirect light).

Every stage is timed (ms, one CSV row per frame, columns :data:`FRAME_COLUMNS`); when asked, the composed
frame is compared with the path-traced GT at the local camera (SSIM/PSNR on tone-mapped images). The GT
renders for evaluation are not part of any stage time.

The one import against SPEC §1's arrows: ``--warp pixel`` loads cloud baking's pixel-level warp, lazily
and only for that comparison, so Table 3 can run both warps inside the same client loop.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import time
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from gicore.blend import COMPOSITIONS, blend, residual
from gicore.camera import Camera
from gicore.metrics import psnr, ssim
from gicore.paths import camera_path, light_position
from gicore.scene import SceneSpec, load_scene
from gicore.tonemap import tonemap
from gigan_local.warp import GITexture, StructureAwareWarp, Timings

if TYPE_CHECKING:
    from gicore.render import Renderer

WARPS = ("structure", "pixel", "none")
GI_SOURCES = ("model", "gt")
#: Per-frame CSV columns: stage times in ms (empty where a stage did not run), then quality.
#: ``valid_frac`` is the fraction of the frame whose GI came from the GI map rather than the fallback or
#: hole filling (background, with nothing to warp, counts as valid).
STAGES = ("di", "gi", "bind", "raster", "project", "depth_test", "lookup", "splat", "fill", "compose")
FRAME_COLUMNS = ("frame", "gi_frame", "gi_age", "valid_frac", *(f"{s}_ms" for s in STAGES), "frame_ms", "ssim", "psnr")


@dataclass(frozen=True)
class ClientConfig:
    """One client run. ``None`` FOVs come from the scene spec (local 60°, GI 90°)."""

    scene: str = "lung_plane"
    frames: int = 60
    resolution: int = 256
    #: GI-map period k: a new GI map every ``every`` frames (Table 3's inference frequency).
    every: int = 30
    gi_fov: float | None = None
    local_fov: float | None = None
    #: Frames per full orbit of the camera path (sets the motion per frame: 360° / orbit_frames).
    orbit_frames: int = 300
    tau: float = 0.0
    composition: str = "blend"
    warp: str = "structure"
    gi_source: str = "gt"
    model: Path | None = None
    #: Samples per pixel of path-traced GT renders (the ``gt`` GI source and the evaluation GT).
    spp: int = 64
    #: Denoise path-traced GT renders with OIDN (albedo/normal guided).
    denoise: bool = True
    #: Compare the composed frame with the GT every ``gt_every`` frames (0: never).
    gt_every: int = 0
    seed: int = 0
    threads: int = 2

    def __post_init__(self) -> None:
        if self.frames < 1 or self.every < 1 or self.orbit_frames < 1:
            raise ValueError(f"frames, every and orbit_frames must be >= 1, got {self.frames}, {self.every}, {self.orbit_frames}")
        if self.gt_every < 0 or self.spp < 1:
            raise ValueError(f"gt_every must be >= 0 and spp >= 1, got {self.gt_every}, {self.spp}")
        if not 0.0 <= self.tau <= 1.0:
            raise ValueError(f"tau must lie in [0, 1], got {self.tau}")
        for name, value, allowed in (("composition", self.composition, COMPOSITIONS), ("warp", self.warp, WARPS), ("gi_source", self.gi_source, GI_SOURCES)):
            if value not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {value!r}")

    def fovs(self, spec: SceneSpec) -> tuple[float, float]:
        """(local FOV, GI FOV) for ``spec``: without warping the GI camera is the local camera."""
        local = self.local_fov or spec.camera.local_fov
        if self.warp != "none":
            return local, self.gi_fov or spec.camera.gi_fov
        if self.gi_fov is not None and self.gi_fov != local:
            raise ValueError(f"warp 'none' pastes the GI map unchanged, so it must be generated with the local FOV ({local}°); drop gi_fov={self.gi_fov}")
        return local, local


def frame_seed(seed: int, purpose: str, frame: int) -> int:
    """Independent, reproducible render seeds per (run seed, purpose, frame)."""
    return zlib.crc32(f"{seed}/{purpose}/{frame}".encode())


# -- GI sources -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GIMap:
    """A GI map and what warping and composition need, all at the GI ``camera``.

    ``radiance``: linear GI (HxWx3); ``di``: the DI the map was generated with (HxWx3); ``depth``: linear
    view depth at texel centres (HxW, 0 = background); ``ms``: what producing it cost (render at the GI
    camera + inference, or the GT stand-in's path tracing).
    """

    camera: Camera
    radiance: np.ndarray
    di: np.ndarray
    depth: np.ndarray
    ms: float


class GISource(Protocol):
    """Makes the GI map at a GI camera for a frame (``frame`` seeds its noise, if any)."""

    name: str

    def __call__(self, camera: Camera, light: tuple[float, float, float], frame: int) -> GIMap: ...


def _texel_depth(renderer: "Renderer", camera: Camera) -> np.ndarray:
    """View depth at texel centres (the centre-sampled pass, so warps unproject exact centre rays)."""
    p = renderer.render_uv(camera)
    return np.where(p["mask"], camera.view_depth(p["position"]), 0.0).astype(np.float32)


def render_gt(renderer: "Renderer", camera: Camera, light, spp: int, seed: int, denoise: bool) -> np.ndarray:
    """Path-traced GT at ``camera``, OIDN-denoised when asked."""
    gt = renderer.render_gt(camera, light, spp=spp, seed=seed)
    return renderer.denoise(gt, renderer.render_gbuffers(camera, seed=seed)) if denoise else gt


@dataclass
class GTSource:
    """The path-traced GT GI map at the GI camera: an oracle stand-in for the generator.

    ``cache`` (optional, shared between runs of a bench) maps render keys to finished GI maps; a cached
    map keeps the cost measured when it was rendered.
    """

    renderer: "Renderer"
    spp: int = 64
    denoise: bool = True
    seed: int = 0
    cache: dict | None = None
    name: str = "gt"

    def __call__(self, camera: Camera, light, frame: int) -> GIMap:
        key = ("gi", camera, tuple(light), self.spp, self.denoise, self.seed, frame)
        if self.cache is not None and key in self.cache:
            return self.cache[key]
        t0 = time.perf_counter()
        radiance = render_gt(self.renderer, camera, light, self.spp, frame_seed(self.seed, "gi", frame), self.denoise)
        di = self.renderer.render_di(camera, light, seed=frame_seed(self.seed, "gi_di", frame))
        gi = GIMap(camera, radiance, di, _texel_depth(self.renderer, camera), (time.perf_counter() - t0) * 1e3)
        if self.cache is not None:
            self.cache[key] = gi
        return gi


@dataclass
class ModelSource:
    """The GIGAN generator (ONNX) on DI + G-buffers rendered at the GI camera."""

    renderer: "Renderer"
    model: Any  # gigan_local.inference.GIModel
    seed: int = 0
    name: str = "model"

    def __call__(self, camera: Camera, light, frame: int) -> GIMap:
        t0 = time.perf_counter()
        buffers = self.renderer.render_di_gbuffers(camera, light, seed=frame_seed(self.seed, "gi_di", frame))
        radiance = np.asarray(self.model.predict(buffers), dtype=np.float32)
        return GIMap(camera, radiance, buffers["di"], _texel_depth(self.renderer, camera), (time.perf_counter() - t0) * 1e3)


def make_gi_source(cfg: ClientConfig, renderer: "Renderer", cache: dict | None = None) -> GISource:
    """The configured GI source; ``model`` needs an exported model (``--model`` or the default file)."""
    if cfg.gi_source == "gt":
        return GTSource(renderer, cfg.spp, cfg.denoise, cfg.seed, cache)
    from gigan_local.inference import DEFAULT_MODEL, GIModel

    path = Path(cfg.model or DEFAULT_MODEL)
    if not path.is_file():
        raise FileNotFoundError(f"no GI model at {path}: export one with gigan-export, pass --model, or use --gi-source gt")

    model = GIModel(path, cfg.threads)
    if model.resolution != renderer.resolution:
        raise ValueError(f"the model at {path} runs at {model.resolution}² but the client renders {renderer.resolution}²; pass --resolution {model.resolution}")
    return ModelSource(renderer, model, cfg.seed)


# -- per frame ------------------------------------------------------------------------------------------
def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


@dataclass
class FrameResult:
    """One composed frame (linear radiance, HxWx3) and its CSV row."""

    image: np.ndarray
    row: dict[str, Any] = field(default_factory=dict)


class ViewWarp:
    """Brings the newest GI map to the current view by one ``method`` of :data:`WARPS`: :meth:`bind`
    once per GI map, then call once per frame.

    What is warped depends on the ``composition``: the GI map itself for ``blend``; its indirect part
    ``max(GI - DI of the GI map, 0)`` for ``residual``, which adds it to the current DI.
    """

    def __init__(self, method: str, renderer: "Renderer", composition: str = "blend"):
        if method not in WARPS:
            raise ValueError(f"warp must be one of {WARPS}, got {method!r}")
        if composition not in COMPOSITIONS:
            raise ValueError(f"composition must be one of {COMPOSITIONS}, got {composition!r}")
        self.method = method
        self.composition = composition
        self.renderer = renderer
        self.warper = StructureAwareWarp(renderer) if method == "structure" else None
        self.pixel_warp: Any = None  # baseline_cloudbaking.warp.PixelWarp of the bound map
        self.gi: GIMap | None = None
        self.image: np.ndarray | None = None

    def bind(self, gi: GIMap) -> Timings:
        """Per-GI-map work: pick what to warp; structure-aware uploads per-vertex coordinates, pixel-level
        unprojects the map into a point cloud."""
        t0 = time.perf_counter()
        self.gi = gi
        indirect = np.maximum(gi.radiance - gi.di, 0.0)
        self.image = gi.radiance if self.composition == "blend" else indirect
        if self.warper is not None:
            self.warper.bind(GITexture.build(gi.camera, self.image, gi.depth, indirect))
        elif self.method == "pixel":
            from baseline_cloudbaking.warp import PixelWarp  # the cloud-baking client's warp, as an ablation

            self.pixel_warp = PixelWarp(self.image, gi.depth, gi.camera)
        return {"bind": _ms(t0)} if self.method != "none" else {}

    def __call__(self, camera: Camera, di: np.ndarray) -> tuple[np.ndarray, np.ndarray, Timings]:
        """The bound map at ``camera``, complete (fallback / hole filling applied), the mask of pixels
        that came from the map (background counts; false where the fallback was needed), and the stage
        timings. ``di`` is the current frame's DI (the fallback uses it)."""
        gi, image = self.gi, self.image
        if gi is None or image is None:
            raise RuntimeError("no GI map is bound; call bind() first")
        if self.method == "none":
            return image, np.ones(gi.depth.shape, dtype=bool), {}
        t0 = time.perf_counter()
        uv_pass = self.renderer.render_uv(camera)
        timings = {"raster": _ms(t0)}
        mask = uv_pass["mask"]
        if self.warper is not None:
            warped, valid, t = self.warper.warp(uv_pass, base=di if self.composition == "blend" else None)
            timings |= t
        else:
            warped, valid, t = self.pixel_warp.warp(camera, target_mask=mask)
            timings |= t
        return warped, valid | ~mask, timings


class GIClient:
    """The per-frame loop of one configured client on one renderer (see the module docstring)."""

    def __init__(self, cfg: ClientConfig, renderer: "Renderer", source: GISource):
        self.cfg = cfg
        self.renderer = renderer
        self.source = source
        self.local_fov, self.gi_fov = cfg.fovs(renderer.spec)
        self.warp = ViewWarp(cfg.warp, renderer, cfg.composition)
        self.gi_frame: int | None = None

    def warm_up(self, camera: Camera, light) -> None:
        """Run every pass once, untimed, so that kernel compilation (Mitsuba JIT-compiles each pass on
        first use) does not land in the first frame's or the first GI map's time."""
        gi = self.source(camera.with_fov(self.gi_fov), light, -1)
        self.warp.bind(gi)
        self.warp(camera, self.renderer.render_di(camera, light))
        self.gi_frame = None

    def step(self, frame: int, camera: Camera, light) -> FrameResult:
        """Render, (maybe) refresh the GI map, warp, compose one frame at the local ``camera``."""
        cfg = self.cfg
        stages: dict[str, float] = {}
        t0 = time.perf_counter()
        di = self.renderer.render_di(camera, light, seed=frame_seed(cfg.seed, "di", frame))
        stages["di"] = _ms(t0)

        is_gi_frame = self.gi_frame is None or frame - self.gi_frame >= cfg.every
        if is_gi_frame:
            gi = self.source(camera.with_fov(self.gi_fov), light, frame)
            self.gi_frame = frame
            stages["gi"] = gi.ms
            stages |= self.warp.bind(gi)

        warped, valid, timings = self.warp(camera, di)
        stages |= timings

        t0 = time.perf_counter()
        # residual: the warped map is already indirect-only, so nothing is subtracted from it
        image = blend(di, warped, cfg.tau) if cfg.composition == "blend" else residual(di, warped, np.zeros_like(di))
        stages["compose"] = _ms(t0)

        row: dict[str, Any] = {"frame": frame, "gi_frame": int(is_gi_frame), "gi_age": frame - self.gi_frame, "valid_frac": float(valid.mean())}
        row |= {f"{s}_ms": stages.get(s, "") for s in STAGES}
        row["frame_ms"] = sum(stages.values())
        return FrameResult(image, row)


def evaluate(image: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """SSIM and PSNR of a composed frame against the GT, both tone-mapped (PSNR may be inf)."""
    a, b = tonemap(image), tonemap(gt)
    return {"ssim": ssim(a, b), "psnr": psnr(a, b)}


def amortized_fps(rows: list[dict[str, Any]], every: int) -> dict[str, float]:
    """Frame rate with the GI-map cost spread over its ``every`` frames.

    ``local_ms``: median per-frame work (everything but GI generation and binding); ``gi_ms``: mean cost
    of one GI map (generation + binding); ``fps = 1000 / (local_ms + gi_ms / every)``.
    """
    local = [r["frame_ms"] - float(r["gi_ms"] or 0.0) - float(r["bind_ms"] or 0.0) for r in rows]
    gi = [float(r["gi_ms"]) + float(r["bind_ms"] or 0.0) for r in rows if r["gi_frame"]]
    local_ms = float(np.median(local))
    gi_ms = float(np.mean(gi)) if gi else 0.0
    return {"local_ms": local_ms, "gi_ms": gi_ms, "fps": 1000.0 / (local_ms + gi_ms / every)}


def run_frames(cfg: ClientConfig, renderer: "Renderer | None" = None, cache: dict | None = None, on_frame=None) -> list[dict[str, Any]]:
    """Run the loop; returns the per-frame rows. ``renderer`` and ``cache`` may be shared between runs
    (a bench); ``on_frame(frame, result)`` sees every composed frame."""
    spec = load_scene(cfg.scene)
    if renderer is None:
        from gicore.render import Renderer

        renderer = Renderer(spec, cfg.resolution)
    elif (renderer.spec.name, renderer.resolution) != (spec.name, cfg.resolution):
        raise ValueError(f"the shared renderer renders {renderer.spec.name} at {renderer.resolution}² but the config asks for {spec.name} at {cfg.resolution}²")
    if cfg.denoise and (cfg.gi_source == "gt" or cfg.gt_every) and importlib.util.find_spec("pyoidn") is None:
        raise ValueError("denoising the GT renders needs pyoidn (pip install pyoidn); or turn it off (--no-denoise)")
    client = GIClient(cfg, renderer, make_gi_source(cfg, renderer, cache))
    cams = camera_path(renderer.spec, cfg.orbit_frames, seed=cfg.seed, fov=client.local_fov, resolution=cfg.resolution)
    client.warm_up(cams[0], light_position(renderer.spec, 0))
    rows = []
    for frame in range(cfg.frames):
        camera, light = cams[frame % cfg.orbit_frames], light_position(renderer.spec, frame)
        result = client.step(frame, camera, light)
        if cfg.gt_every and frame % cfg.gt_every == 0:
            key = ("gt", camera, tuple(light), cfg.spp, cfg.denoise, cfg.seed, frame)
            if cache is not None and key in cache:
                gt = cache[key]
            else:
                gt = render_gt(renderer, camera, light, cfg.spp, frame_seed(cfg.seed, "gt", frame), cfg.denoise)
                if cache is not None:
                    cache[key] = gt
            result.row |= evaluate(result.image, gt)
        else:
            result.row |= {"ssim": "", "psnr": ""}
        rows.append(result.row)
        if on_frame is not None:
            on_frame(frame, result)
    return rows


def summarize(cfg: ClientConfig, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Run summary: amortised fps, median stage times, mean quality over the evaluated frames."""
    scored = [r for r in rows if r["ssim"] != ""]
    out: dict[str, Any] = {"config": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()}}
    out |= amortized_fps(rows, cfg.every)
    out["median_ms"] = {s: float(np.median(v)) for s in STAGES if (v := [float(r[f"{s}_ms"]) for r in rows if r[f"{s}_ms"] != ""])}
    if scored:
        out["mean_ssim"] = float(np.mean([r["ssim"] for r in scored]))
        finite = [r["psnr"] for r in scored if math.isfinite(r["psnr"])]
        out["mean_psnr"] = float(np.mean(finite)) if finite else math.inf
    return out


def write_rows(rows: list[dict[str, Any]], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=FRAME_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return path


def run(cfg: ClientConfig, out: Path, save_frames: bool = False, video: bool = False) -> dict[str, Any]:
    """Run the client and write ``frames.csv``, ``summary.json`` and optionally PNG frames / an MP4."""
    from PIL import Image

    out = Path(out)
    frames_dir = out / "frames"
    images: list[np.ndarray] = []

    def keep(frame: int, result: FrameResult) -> None:
        rgb = (np.clip(tonemap(result.image), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        if save_frames:
            frames_dir.mkdir(parents=True, exist_ok=True)
            Image.fromarray(rgb).save(frames_dir / f"frame_{frame:05d}.png")
        if video:
            images.append(rgb)

    rows = run_frames(cfg, on_frame=keep if (save_frames or video) else None)
    write_rows(rows, out / "frames.csv")
    summary = summarize(cfg, rows)
    if video:
        summary["video"] = _write_video(images, out / "frames.mp4")
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def _write_video(images: list[np.ndarray], path: Path) -> str | None:
    """An MP4 of the frames when imageio-ffmpeg is installed; otherwise None (and a message)."""
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401  (the MP4 writer's backend)
    except ImportError:
        print("imageio-ffmpeg is not installed: skipping the MP4 (PNG frames are unaffected)")
        return None
    imageio.mimwrite(path, images, fps=30)
    return str(path)
