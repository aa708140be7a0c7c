"""The GIGAN client (paper III, Fig. 1): its GI sources, and `gigan-client`'s run on the shared loop.

The loop itself -- DI every frame, a GI map every ``k`` frames, warp, compose, per-frame rows -- is
:mod:`gicore.loop`'s, shared with the cloud-baking client. GIGAN brings:

- :class:`ModelSource`: the exported generator (:func:`gigan_local.backend_choice.open_model`: onnxruntime,
  or torch on a CUDA GPU) on DI + G-buffers it renders at the GI camera (FOV ``F_GI``, default 90°); both the
  render (``gi_render``) and the inference count as GIGAN's stages;
- :class:`GTSource`: the path-traced GT GI map at the GI camera, an oracle stand-in for a perfect model
  (so the loop runs without a trained model; its cost is path tracing, not a network's);
- the structure-aware warp (:class:`gigan_local.warp.StructureAwareWarp`), or none (the map pasted as
  is, so it is made with the local camera's FOV).

With ``renderer="gl"`` (:attr:`gicore.run_config.PathRunConfig.renderer`) every per-frame raster pass -- the local
DI, the model source's DI + G-buffers at the GI camera, the warp's uv pass -- is OpenGL's
(:class:`gicore.gl.GLRenderer` at level of detail :data:`gicore.run_config.CLIENT_LOD`); path tracing (the GT
source, GT scoring) stays Mitsuba's, so such a client holds both renderers; a model-source client on GL without
GT scoring opens no Mitsuba at all (:func:`needs_path_tracer`). The stage names are the same either way.

GIGAN maps with cloud baking's pixel-level warp (Table 3's comparison) are assembled in ``bench``, which
may import both systems; this package does not import ``baseline_cloudbaking``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.frame_rows import summarize, write_rows
from gicore.gi_map import LAYERS, GIMap, texel_depth
from gicore.ground_truth import render_gt
from gicore.loop import ClientLoop, FrameResult, LoopConfig, PasteWarp, SynchronousSource, Warp, run_frames
from gicore.mitsuba_variant import check_denoiser
from gicore.options import THREADS
from gicore.path_file import PathFile, flown_path, write_path_file
from gicore.paths import Light, frame_seed
from gicore.run_config import PathRunConfig
from gicore.scene import SceneSpec, load_scene
from gicore.timing import Stopwatch
from gicore.tonemap import tonemap
from gigan_local.backend_choice import INFERENCE_BACKENDS, resolve_inference
from gigan_local.warp import StructureAwareWarp

if TYPE_CHECKING:
    from gicore.render import Renderer
    from gigan_local.inference import ExportedGenerator

#: GIGAN's warps: structure-aware (Alg. 1), or none (the map pasted as is, made at the local FOV).
WARPS = ("structure", "none")
#: GI sources: the ONNX generator, or the path-traced GT stand-in.
GI_SOURCES = ("model", "gt")
#: The stages of a map's interaction latency (:func:`stage_samples`): the DI of the frame showing it, the map's
#: GI-camera render and inference, the warp and the blend.
MAP_STAGES = ("di", "gi_render", "inference", "warp", "blend")


@dataclass(frozen=True)
class ClientConfig(PathRunConfig):
    """One `gigan-client` run: the shared path run plus GIGAN's GI source and warp (its command line is
    derived from these fields and :class:`~gicore.run_config.PathRunConfig`'s)."""

    #: Warp: structure (Alg. 1) or none (the map pasted as is, made at the local FOV).
    warp: Literal[WARPS] = "structure"  # type: ignore[valid-type]
    #: GI source: model (ONNX generator) or gt (path-traced GT stand-in).
    gi_source: Literal[GI_SOURCES] = "gt"  # type: ignore[valid-type]
    #: ONNX model; absent: the shipped gigan_local/models/gigan_default/model_fp16.onnx.
    model: Path | None = None
    #: onnxruntime threads (torch's on the CPU).
    threads: int = field(default=2, metadata=THREADS)
    #: Backend of the model source's inference: auto (torch on a CUDA GPU, in float16, where torch sees one; else
    #: onnxruntime), onnxruntime (CPU) or torch (CUDA where there is one, else the CPU in float32).
    inference: Literal[INFERENCE_BACKENDS] = "auto"  # type: ignore[valid-type]

    def check(self) -> None:
        """A given model must be a file (checked before the run, as the command line builds the config)."""
        if self.model is not None and not Path(self.model).is_file():
            raise UserError(
                f"--model {self.model} is not a file",
                "give an ONNX file written by gigan-export, or leave --model out for the shipped model",
            )

    def fovs(self, spec: SceneSpec) -> tuple[float, float]:
        """(local FOV, GI FOV) for ``spec``: without warping the GI camera is the local camera."""
        local = self.local_fov_of(spec)
        if self.warp != "none":
            return local, self.gi_fov_of(spec)
        if self.gi_fov is not None and self.gi_fov != local:
            raise UserError(
                f"--warp none pastes the GI map unchanged, so it must be made with the local FOV ({local}°)",
                f"drop --gi-fov {self.gi_fov}",
            )
        return local, local

    def loop_config(self, spec: SceneSpec) -> LoopConfig:
        # without warping the GI camera is the frame's own camera (gi_fov None), whatever FOV its path gives it
        gi_fov = None if self.warp == "none" else self.fovs(spec)[1]
        return LoopConfig(every=self.every, gi_fov=gi_fov, composition=self.composition, tau=self.tau, seed=self.seed)


# -- GI sources ---------------------------------------------------------------------------------------------
class GTSource(SynchronousSource):
    """The path-traced GT GI map at the GI camera (OIDN-denoised when asked), the DI it holds and its
    depth: an oracle stand-in for the generator.

    ``cache`` (optional, shared between runs of a bench) keeps finished maps by render key; a cached map
    keeps the cost measured when it was rendered (its ``stages``).
    """

    name = "gt"
    stages = ("gt_render",)

    def __init__(
        self, renderer: Renderer, spp: int = 64, denoise: bool = True, seed: int = 0, cache: dict | None = None
    ):
        super().__init__()
        self.renderer, self.spp, self.denoise, self.seed, self.cache = renderer, spp, denoise, seed, cache

    def produce(self, camera: Camera, light: Light, frame: int) -> GIMap:
        key = ("gi", camera, tuple(light), self.spp, self.denoise, self.seed, frame)
        if self.cache is not None and key in self.cache:
            return self.cache[key]
        sw = Stopwatch()
        radiance = render_gt(self.renderer, camera, light, self.spp, frame_seed(self.seed, "gi", frame), self.denoise)
        di = self.renderer.render_di(camera, light, seed=frame_seed(self.seed, "gi_di", frame))
        depth = texel_depth(self.renderer, camera)
        sw.lap("gt_render")
        gi = GIMap(camera, radiance, depth, di, stages=sw.ms)
        if self.cache is not None:
            self.cache[key] = gi
        return gi


class ModelSource(SynchronousSource):
    """The GIGAN generator (an exported model on its inference backend) on DI + G-buffers rendered at the GI camera.

    Stages: ``gi_render`` (DI, and G-buffers sampled at pixel centres as a rasteriser samples them, so that
    their depth is also the texel-centre depth the warp's occlusion test reads: no separate depth pass)
    and ``inference`` (:meth:`~gigan_local.inference.ExportedGenerator.predict`: encoding, host copies to and
    from the backend's device, and decoding included). Centre-sampled G-buffers
    leave the shipped model's quality as it was with the jittered ones it was trained on: mean SSIM
    against path-traced GT at the GI camera 0.9331 vs 0.9326 (30 views, five scenes, paired difference
    0.0004 +- 0.0004).
    """

    name = "model"
    stages = ("gi_render", "inference")

    def __init__(self, renderer: Renderer, model: ExportedGenerator, seed: int = 0):
        super().__init__()
        self.renderer, self.model, self.seed = renderer, model, seed
        self._buffers = {*model.buffers, "depth"}  # the network's inputs and the map's depth

    def produce(self, camera: Camera, light: Light, frame: int) -> GIMap:
        sw = Stopwatch()
        seed = frame_seed(self.seed, "gi_di", frame)
        buffers = self.renderer.render_di_gbuffers(camera, light, seed, centre=True, buffers=self._buffers)
        sw.lap("gi_render")
        radiance = self.model.predict(buffers)
        sw.lap("inference")
        return GIMap(camera, radiance, buffers["depth"][..., 0], buffers["di"], stages=sw.ms)


def load_model(path: Path | None, threads: int, resolution: int, inference: str = "auto") -> ExportedGenerator:
    """The ONNX model at ``path`` (default: the shipped one) on the backend ``inference`` chooses
    (:data:`~gigan_local.backend_choice.INFERENCE_BACKENDS`), checked against the client's resolution."""
    from gigan_local.backend_choice import open_model
    from gigan_local.inference import DEFAULT_MODEL

    path = Path(path or DEFAULT_MODEL)
    if not path.is_file():
        raise UserError(f"no GI model at {path}", "export one with gigan-export, pass --model, or use --gi-source gt")
    model = open_model(path, inference, threads)
    if model.resolution != resolution:
        raise UserError(
            f"the model at {path} runs at {model.resolution}² but the client renders {resolution}²",
            f"pass --resolution {model.resolution}",
        )
    return model


def make_gi_source(
    cfg: ClientConfig, renderer: Renderer | None, cache: dict | None = None, raster: Any | None = None
) -> SynchronousSource:
    """The configured GI source; ``model`` needs an exported model (``--model`` or the default file).

    ``renderer`` path-traces (the ``gt`` source is Mitsuba's alone); ``raster`` (default ``renderer``)
    renders the model source's DI + G-buffers at the GI camera (a :class:`gicore.gl.GLRenderer` with
    ``renderer="gl"``)."""
    if cfg.gi_source == "gt":
        return GTSource(renderer, cfg.spp, cfg.denoise, cfg.seed, cache)
    raster = renderer if raster is None else raster
    return ModelSource(raster, load_model(cfg.model, cfg.threads, raster.resolution, cfg.inference), cfg.seed)


def make_warp(method: str, renderer: Renderer, composition: str, backend: str = "numpy") -> Warp:
    """GIGAN's warp ``method`` (:data:`WARPS`) for ``composition`` (which layer of the map it warps), on
    ``backend`` (``numpy``, or ``gl``: :class:`gigan_local.gl_warp.GLStructureWarp` on a GL ``renderer``)."""
    if method not in WARPS:
        raise ValueError(f"warp must be one of {WARPS}, got {method!r}")
    layer = LAYERS[composition]
    if method == "none":
        return PasteWarp(layer)
    if backend == "gl":
        from gigan_local.gl_warp import GLStructureWarp

        return GLStructureWarp(renderer, layer)
    return StructureAwareWarp(renderer, layer)


# -- a run --------------------------------------------------------------------------------------------------
def needs_path_tracer(cfg: ClientConfig) -> bool:
    """Whether a run of ``cfg`` path-traces (Mitsuba): the GT source, GT scoring, or Mitsuba's raster passes.
    A model-source client on GL without GT is Mitsuba-free, as a browser client is."""
    return cfg.renderer == "mitsuba" or cfg.gi_source == "gt" or bool(cfg.gt_every)


def open_renderers(
    cfg: ClientConfig, spec: SceneSpec, renderer: Renderer | None = None
) -> tuple[Renderer | None, Any, str]:
    """(Mitsuba renderer or None, the renderer of the per-frame raster passes, the name of the one that runs them).

    ``renderer``: a Mitsuba renderer to share (it must render ``spec`` at the config's resolution); without
    one, one is opened where the run needs it (:func:`needs_path_tracer`) or GL does not open. With
    ``cfg.renderer == "gl"`` the raster passes get a :class:`gicore.gl.GLRenderer`, or Mitsuba's after one
    warning when no GL context opens (:func:`gicore.gl.frame.open_client_raster`)."""
    if renderer is not None and (renderer.spec.name, renderer.resolution) != (spec.name, cfg.resolution):
        raise ValueError(
            f"the shared renderer renders {renderer.spec.name} at {renderer.resolution}²"
            f" but the config asks for {spec.name} at {cfg.resolution}²"
        )
    if renderer is None and needs_path_tracer(cfg):
        renderer = _path_renderer(spec, cfg.resolution)
    from gicore.gl.frame import open_client_raster

    raster, used = open_client_raster(cfg.renderer, spec, cfg.resolution, renderer)
    if raster is None:  # GL did not open and nothing had needed Mitsuba until now
        renderer = raster = _path_renderer(spec, cfg.resolution)
    return renderer, raster, used


def _path_renderer(spec: SceneSpec, resolution: int) -> Renderer:
    from gicore.render import Renderer

    return Renderer(spec, resolution)


def run_client(
    cfg: ClientConfig,
    renderer: Renderer | None = None,
    on_frame=None,
    raster: Any | None = None,
    flown: PathFile | None = None,
) -> list[dict[str, Any]]:
    """Run the configured client along its path (``flown``; default: :func:`gicore.path_file.flown_path` of
    ``cfg``); returns the per-frame rows.

    ``renderer`` (optional, shared): the Mitsuba renderer of path tracing; ``raster`` (optional): the
    renderer of the per-frame raster passes (local DI, the model source's DI + G-buffers, the warp's uv
    pass), by default the one ``cfg.renderer`` names (:func:`open_renderers`). GT stays with Mitsuba."""
    spec = load_scene(cfg.scene)
    if raster is None:
        renderer, raster, _ = open_renderers(cfg, spec, renderer)
    elif renderer is None and needs_path_tracer(cfg):
        renderer = _path_renderer(spec, cfg.resolution)
    if cfg.gi_source == "gt" or cfg.gt_every:
        check_denoiser(cfg.denoise)
    local_fov, _ = cfg.fovs(spec)
    source = make_gi_source(cfg, renderer, raster=raster)
    from gicore.gl.frame import warp_backend

    backend = warp_backend(cfg.warp_backend, getattr(raster, "name", "mitsuba"), warn=True)
    loop = ClientLoop(cfg.loop_config(spec), raster, source, make_warp(cfg.warp, raster, cfg.composition, backend))
    views = (flown or flown_path(spec, cfg, cfg.seed, local_fov)).views(cfg.resolution)
    ground_truth = cfg.ground_truth(renderer, spec) if cfg.gt_every else None
    return run_frames(loop, views, ground_truth, on_frame, cfg.frame_rate)


def run(cfg: ClientConfig, out: Path, save_frames: bool = False, video: bool = False) -> dict[str, Any]:
    """Run the client and write ``path.json`` (the path it flies, :mod:`gicore.path_file`), ``frames.csv``,
    ``summary.json`` (with ``frames``, and ``renderer``: the renderer that ran the raster passes, which is
    mitsuba when gl was asked and no GL context opened) and optionally PNG frames / an MP4."""
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

    spec = load_scene(cfg.scene)
    flown = flown_path(spec, cfg, cfg.seed, cfg.fovs(spec)[0])
    renderer, raster, used = open_renderers(cfg, spec)
    rows = run_client(cfg, renderer, on_frame=keep if (save_frames or video) else None, raster=raster, flown=flown)
    out.mkdir(parents=True, exist_ok=True)  # after the run: a bad model or scene writes nothing
    write_path_file(out / "path.json", flown.scene, flown.frames, flown.source)
    write_rows(rows, out / "frames.csv")
    summary = {"config": cfg.as_json(), "frames": len(rows)}
    from gicore.gl.frame import warp_backend

    summary |= {"renderer": used, "warp_backend": warp_backend(cfg.warp_backend, used)} | summarize(rows, cfg.every)
    if cfg.gi_source == "model":
        summary["inference"] = resolve_inference(cfg.inference)
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


def stages_of_run(cfg: ClientConfig) -> dict[str, list[float]]:
    """Run ``cfg`` in this process: its per-map stage samples (:func:`stage_samples`)."""
    return stage_samples([{k: str(v) for k, v in row.items()} for row in run_client(cfg)])


def stage_samples(frames: list[dict[str, str]]) -> dict[str, list[float]]:
    """Per-map stage times (ms) of a run's ``frames.csv`` rows, :data:`MAP_STAGES` and their ``total``: one sample
    per frame that bound a new map; ``warp`` is the bind and the per-frame warp stages of the backend the run used
    (``--warp-backend``: the columns it has)."""
    from gigan_local.gl_warp import GLStructureWarp

    per_frame = dict.fromkeys(s for w in (StructureAwareWarp, GLStructureWarp) for s in w.stages if s != "bind")
    samples: dict[str, list[float]] = {s: [] for s in (*MAP_STAGES, "total")}
    for row in (r for r in frames if r["gi_new"] == "1"):
        stage = {
            "di": float(row["di_ms"]),
            "gi_render": float(row["gi_render_ms"]),
            "inference": float(row["inference_ms"]),
            "warp": float(row["bind_ms"]) + sum(float(row[f"{s}_ms"]) for s in per_frame if f"{s}_ms" in row),
            "blend": float(row["compose_ms"]),
        }
        for name, ms in stage.items():
            samples[name].append(ms)
        samples["total"].append(sum(stage.values()))
    return samples
