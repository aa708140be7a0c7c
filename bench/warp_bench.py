"""`bench warp` (paper Fig. 7): CPU cost, load, memory and quality of pixel-level (cloud baking) vs
structure-aware (GIGAN, Alg. 1) 3D image warping, side by side in one run (docs/architecture.md, bench warp)."""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from bench.common import WARP_LABELS
from bench.runner import FOV_DEGREES, Bench, Block, Section
from gicore import option_groups
from gicore.camera import Camera
from gicore.gl.frame import open_client_raster
from gicore.gl.lod import LOD_CHOICES, lod_value
from gicore.metrics import ssim
from gicore.paths import camera_path, light_position
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, wide
from gicore.results import Results
from gicore.run_config import CLIENT_LOD, RENDERERS
from gicore.scene import SceneSpec, load_scene
from gicore.timing import peak_mib
from gicore.tonemap import tonemap

if TYPE_CHECKING:
    from gicore.render import Renderer

SYSTEMS = {m: WARP_LABELS[m] for m in ("structure", "pixel")}


@dataclass(frozen=True)
class WarpBenchConfig:
    """The parameter grid of one run."""

    scenes: tuple[str, ...] = option_groups.scenes(("lung_plane", "digestive_plane", "vessels_plane"))
    resolution: int = option_groups.resolution()
    #: FOV of the local (client) camera, degrees.
    local_fov: float = field(default=60.0, metadata=FOV_DEGREES)
    #: FOV of the GI camera whose map is warped, degrees.
    gi_fov: float = field(default=90.0, metadata=FOV_DEGREES)
    #: Frames along the camera path where GI maps are made.
    gi_frames: tuple[int, ...] = field(default=(0, 100, 200), metadata={"min": 0})
    #: Local frames after each GI frame that the map is warped to (camera motion).
    offsets: tuple[int, ...] = (1, 5, 10, 15, 20, 25, 29)
    orbit_frames: int = option_groups.orbit_frames()
    spp: int = option_groups.spp(note="of the path-traced GI maps and GT")
    denoise: bool = option_groups.denoise()
    #: Timed calls of each method per local frame (alternating the two).
    repeats: int = 10
    #: Untimed calls of each method per local frame before timing.
    warmup: int = field(default=2, metadata={"min": 0})
    #: Renderer of the local passes (the warps' uv and surface-mask passes, the DI): gl (OpenGL; without a GL
    #: context one warning and mitsuba) or mitsuba. GI maps and GT are path-traced by Mitsuba either way.
    renderer: Literal[RENDERERS] = "gl"  # type: ignore[valid-type]
    #: Level of detail of the gl passes (gicore.gl.GLRenderer's lod; default the clients': auto, per view).
    gl_lod: Literal[LOD_CHOICES] = CLIENT_LOD  # type: ignore[valid-type]

    @classmethod
    def quick(cls) -> WarpBenchConfig:
        return cls(gi_frames=(0,), offsets=(1, 10, 20, 29), spp=16, repeats=5)


#: Each method's raster pass, and DI alone.
PASSES = {"structure": "uv", "pixel": "mask", "di": None}


@dataclass
class _Scene:
    """One scene of a run: its renderers (the local raster is ``used``: gl or mitsuba), fly-through, GT maps
    and structure-aware warper, the config columns of its rows, and the run's seed."""

    name: str
    spec: SceneSpec
    renderer: Renderer
    raster: Any
    used: str
    cams: list[Camera]
    source: Any
    warper: Any
    common: dict[str, Any]
    seed: int
    #: The warps' GL backends by method (gigan_local.gl_warp, baseline_cloudbaking.gl_warp); none off GL.
    shaders: dict[str, Any] = field(default_factory=dict)


@dataclass
class _Tally:
    """What a scene's run collects: timings (s) by name, stage times and CPU (cpu s, wall s, calls) per method,
    peak MiB, quality, the uv errors, the gl levels drawn; ``order``: the raster passes, first in turn."""

    samples: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    stages: dict[str, dict[str, list[float]]] = field(default_factory=lambda: {m: defaultdict(list) for m in SYSTEMS})
    cpu: dict[str, list[float]] = field(default_factory=lambda: {m: [0.0, 0.0, 0] for m in SYSTEMS})
    peaks: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    quality: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    uv_err: dict[str, list[np.ndarray]] = field(default_factory=lambda: defaultdict(list))
    levels: list[int] = field(default_factory=list)
    order: list[str] = field(default_factory=lambda: list(PASSES))


def measure(cfg: WarpBenchConfig, res: Results) -> None:
    for name in cfg.scenes:
        scene = _open_scene(cfg, name, res.seed)
        for pass_name in PASSES.values():  # untimed: a pass's first call compiles its program
            scene.raster.render_di_raster(scene.cams[0], light_position(scene.spec, 0), pass_name)
        tally = _Tally()
        for g in cfg.gi_frames:
            _measure_gi_frame(cfg, scene, g, tally, res)
        _record(cfg, scene, tally, res)


def _open_scene(cfg: WarpBenchConfig, name: str, seed: int) -> _Scene:
    from gicore.render import Renderer
    from gigan_local.client import GTSource
    from gigan_local.warp import StructureAwareWarp

    spec = load_scene(name)
    renderer = Renderer(spec, cfg.resolution)
    raster, used = open_client_raster(cfg.renderer, spec, cfg.resolution, renderer, lod_value(cfg.gl_lod))
    common: dict[str, Any] = {"resolution": cfg.resolution, "gi_fov": cfg.gi_fov, "local_fov": cfg.local_fov}
    common |= {"renderer": used} | ({"gl_lod": cfg.gl_lod} if used == "gl" else {})
    cams = camera_path(spec, cfg.orbit_frames, seed=seed, fov=cfg.local_fov, resolution=cfg.resolution)
    source = GTSource(renderer, cfg.spp, cfg.denoise, seed)
    scene = _Scene(name, spec, renderer, raster, used, cams, source, StructureAwareWarp(raster), common, seed)
    if used == "gl":
        from baseline_cloudbaking.gl_warp import GLPixelWarp
        from gigan_local.gl_warp import GLStructureWarp

        scene.shaders = {"structure": GLStructureWarp(raster), "pixel": GLPixelWarp(raster)}
    return scene


def _measure_gi_frame(cfg: WarpBenchConfig, scene: _Scene, g: int, tally: _Tally, res: Results) -> None:
    """GI frame ``g``: its GT map bound by both methods (timed), then warped to each offset's camera; the uv
    errors at the last offset."""
    from baseline_cloudbaking.warp import PointCloud

    light = light_position(scene.spec, g)
    gi = scene.source.produce(scene.cams[g % cfg.orbit_frames].with_fov(cfg.gi_fov), light, g)
    t0 = time.perf_counter()
    scene.warper.bind(gi)
    t1 = time.perf_counter()
    cloud = PointCloud(gi.radiance, gi.depth, gi.camera)
    tally.samples["bind/structure"].append(t1 - t0)
    tally.samples["bind/pixel"].append(time.perf_counter() - t1)
    for m, shader in scene.shaders.items():
        tally.samples[f"gl_bind/{m}"].append(shader.bind(gi)["bind"] / 1e3)
    for offset in cfg.offsets:
        _measure_offset(cfg, scene, g, offset, light, cloud, tally, res)
    last = scene.cams[(g + cfg.offsets[-1]) % cfg.orbit_frames]
    for method, errors in scene.warper.coordinate_errors(last).items():
        tally.uv_err[method].append(errors)


def _measure_offset(
    cfg: WarpBenchConfig, scene: _Scene, g: int, offset: int, light, cloud: Any, tally: _Tally, res: Results
) -> None:
    """The local frame ``offset`` frames after GI frame ``g``: each method's raster pass and warp timed, then
    its peak memory and its SSIM against the path-traced GT there."""
    frame = g + offset
    cam = scene.cams[frame % cfg.orbit_frames]
    raster = scene.raster
    raster.render_di_raster(cam, light)  # untimed: this light's shadow map, which no timed pass redraws
    rendered = {}
    tally.order = tally.order[1:] + tally.order[:1]  # each pass first in turn
    for m in tally.order:
        t0 = time.perf_counter()
        rendered[m] = raster.render_di_raster(cam, light, PASSES[m], seed=frame)
        tally.samples[f"raster/{m}"].append(time.perf_counter() - t0)
        if m == "structure" and scene.used == "gl":
            tally.levels.append(raster.last_level)
    di, uv_pass = rendered["structure"]
    mask = rendered["pixel"][1]["mask"]
    methods = {
        "structure": lambda: scene.warper.resample(uv_pass, base=di),
        "pixel": lambda: cloud.splat(cam, target_mask=mask),
    }
    _time_methods(cfg, methods, tally)
    _score_methods(cfg, scene, methods, cam, light, frame, mask, tally)
    if scene.shaders:
        _time_backends(cfg, scene, cam, light, cloud, tally)
    for m in methods:
        res.add(system=SYSTEMS[m], scene=scene.name, metric="ssim", value=tally.quality[f"{m}/ssim"][-1], unit="1",
                offset=offset, gi_frame=g, **scene.common)  # fmt: skip


def _time_methods(cfg: WarpBenchConfig, methods: dict[str, Callable[[], Any]], tally: _Tally) -> None:
    """Each method's warp after ``cfg.warmup`` untimed calls, ``cfg.repeats`` times, alternating the two so
    both see the same machine load: wall time, stage times and process CPU time."""
    for fn in methods.values():
        for _ in range(cfg.warmup):
            fn()
    for _ in range(cfg.repeats):
        for m, fn in methods.items():
            c0, t0 = time.process_time(), time.perf_counter()
            _, _, t = fn()
            wall, c1 = time.perf_counter() - t0, time.process_time()
            tally.samples[m].append(wall)
            tally.cpu[m][0] += c1 - c0
            tally.cpu[m][1] += wall
            tally.cpu[m][2] += 1
            for stage, ms in t.items():
                tally.stages[m][stage].append(ms / 1e3)


def _time_backends(cfg: WarpBenchConfig, scene: _Scene, cam: Camera, light, cloud: Any, tally: _Tally) -> None:
    """Each method's whole frame on both warp backends, alternating, after ``cfg.warmup`` untimed calls: numpy
    (the DI and the method's pass read back, the warp, eq. 1's blend) and gl (drawn, warped and composed in
    shaders, the frame read back: ``ShaderWarp.frame``, with its stage times); then how far the gl warp's map
    lies from the numpy warp's."""
    from gicore.blend import blend

    def numpy_frame(m: str) -> np.ndarray:
        di, passes = scene.raster.render_di_raster(cam, light, PASSES[m])
        return blend(di, warped(m, di, passes), 0.0)

    def warped(m: str, di: np.ndarray, passes: dict) -> np.ndarray:
        return scene.warper.warp(cam, di, passes)[0] if m == "structure" else cloud.splat(cam, passes["mask"])[0]

    frames = {(m, "numpy"): partial(numpy_frame, m) for m in SYSTEMS}
    frames |= {(m, "gl"): partial(scene.shaders[m].frame, scene.raster, cam, light, "blend", 0.0, 0) for m in SYSTEMS}
    for fn in frames.values():
        for _ in range(cfg.warmup):
            fn()
    for _ in range(cfg.repeats):
        for (m, backend), fn in frames.items():
            t0 = time.perf_counter()
            out = fn()
            tally.samples[f"frame/{m}/{backend}"].append(time.perf_counter() - t0)
            for stage, ms in out[2].items() if backend == "gl" else ():
                tally.samples[f"gl_stage/{m}/{stage}"].append(ms / 1e3)
    for m in SYSTEMS:
        host = warped(m, *scene.raster.render_di_raster(cam, light, PASSES[m]))
        tally.quality[f"{m}/gl_max_abs"].append(float(np.abs(scene.shaders[m].warped(cam, light)[0] - host).max()))


def _record_backends(scene: _Scene, tally: _Tally, res: Results, row: dict[str, Any]) -> None:
    """Per method, its frame on each warp backend, the gl backend's bind and stages, the gl / numpy frame time
    ratio and the largest |gl - numpy| of the warped map."""
    for m, system in SYSTEMS.items():
        frames = {b: tally.samples[f"frame/{m}/{b}"] for b in ("numpy", "gl")}
        for backend, samples in frames.items():
            res.add_timing(system=system, scene=scene.name, metric=f"frame_time:{backend}", samples_s=samples, **row)
        stages = {"bind": tally.samples[f"gl_bind/{m}"]}
        stages |= {k.rsplit("/", 1)[1]: v for k, v in tally.samples.items() if k.startswith(f"gl_stage/{m}/")}
        for stage, samples in stages.items():
            res.add_timing(system=system, scene=scene.name, metric=f"gl_stage_time:{stage}", samples_s=samples, **row)
        ratio = float(np.median(frames["gl"]) / np.median(frames["numpy"]))
        res.add(system=system, scene=scene.name, metric="gl_numpy_ratio", value=ratio, unit="x", stat="median", **row)
        diff = float(np.max(tally.quality[f"{m}/gl_max_abs"]))
        res.add(system=system, scene=scene.name, metric="gl_max_abs", value=diff, unit="1", stat="max", **row)


def _score_methods(
    cfg: WarpBenchConfig, scene: _Scene, methods: dict[str, Callable[[], Any]], cam: Camera, light, frame: int,
    mask: np.ndarray, tally: _Tally,
) -> None:  # fmt: skip
    """Each method's peak memory, and the SSIM of its warped map against the path-traced GT at ``cam`` and the
    share of surface pixels it covers."""
    from gicore.ground_truth import render_gt

    gt = tonemap(render_gt(scene.renderer, cam, light, cfg.spp, scene.seed + 7919 * frame + 1, cfg.denoise))
    for m, fn in methods.items():
        tally.peaks[m].append(peak_mib(fn))
        gi_w, valid, _ = fn()
        tally.quality[f"{m}/ssim"].append(ssim(tonemap(gi_w), gt))
        tally.quality[f"{m}/valid"].append(float(valid[mask].mean()) if mask.any() else 1.0)


def _record(cfg: WarpBenchConfig, scene: _Scene, tally: _Tally, res: Results) -> None:
    """A scene's rows: per method its timings, CPU, memory and quality; the binds and raster passes; the
    pixel / structure ratios; the uv errors."""
    name, cpu = scene.name, tally.cpu
    row = scene.common | {"repeats": cfg.repeats, "frames": len(cfg.gi_frames) * len(cfg.offsets), "spp": cfg.spp}
    row |= {"gl_level_mean": float(np.mean(tally.levels))} if tally.levels else {}
    for m, system in SYSTEMS.items():
        res.add_timing(system=system, scene=name, metric="warp_time", samples_s=tally.samples[m], **row)
        for stage, values in tally.stages[m].items():
            res.add_timing(system=system, scene=name, metric=f"stage_time:{stage}", samples_s=values, **row)
        cpu_s, wall_s, calls = cpu[m]
        for metric, value, unit, stat in (
            ("cpu_time", cpu_s / calls * 1e3, "ms", "mean"),
            ("cpu_percent", 100.0 * cpu_s / wall_s, "%", "mean"),
            ("peak_memory", float(np.max(tally.peaks[m])), "MiB", "max"),
            ("ssim", float(np.mean(tally.quality[f"{m}/ssim"])), "1", "mean"),
            ("valid_fraction", float(np.mean(tally.quality[f"{m}/valid"])), "1", "mean"),
        ):
            res.add(system=system, scene=name, metric=metric, value=value, unit=unit, stat=stat, **row)
    n_vertices = sum(len(o.mesh.vertices) for o in scene.raster.objects)
    res.add_timing(system="structure-aware", scene=name, metric="bind_time", samples_s=tally.samples["bind/structure"],
                   vertices=n_vertices, **row)  # fmt: skip
    res.add_timing(system="pixel-level", scene=name, metric="bind_time", samples_s=tally.samples["bind/pixel"], **row)
    for m, system in (*SYSTEMS.items(), ("di", "DI alone")):
        res.add_timing(system=system, scene=name, metric="raster_time", samples_s=tally.samples[f"raster/{m}"], **row)
    ratio = float(np.median(tally.samples["pixel"]) / np.median(tally.samples["structure"]))
    cpu_ratio = cpu["pixel"][0] / cpu["pixel"][2] / (cpu["structure"][0] / cpu["structure"][2])
    res.add(system="pixel/structure", scene=name, metric="time_ratio", value=ratio, unit="x", stat="median", **row)
    res.add(system="pixel/structure", scene=name, metric="cpu_ratio", value=cpu_ratio, unit="x", stat="mean", **row)
    for method, errors in tally.uv_err.items():
        e = np.concatenate(errors)
        for stat, value in (("median", np.median(e)), ("p99", np.percentile(e, 99)), ("max", e.max())):
            res.add(system=method, scene=name, metric="uv_error", value=float(value), unit="px", stat=stat, **row)
    if scene.shaders:
        _record_backends(scene, tally, res, row)


# -- what it shows ------------------------------------------------------------------------------------------
def _costs(rows: Rows) -> list[dict]:
    """Per scene and warp: time per frame (median, p95), CPU and SSIM (means)."""
    fields = {"median": "warp_time/median", "p95": "warp_time/p95", "cpu": "cpu_percent/mean", "ssim": "ssim/mean"}
    return wide(rows, ("scene", "system"), fields)


def _backends(rows: Rows) -> list[dict]:
    """Per scene and warp: a frame's time on each warp backend (medians), their ratio and the warped maps' gap."""
    fields = {"numpy": "frame_time:numpy/median", "gl": "frame_time:gl/median", "ratio": "gl_numpy_ratio"}
    return wide(rows, ("scene", "system"), fields | {"diff": "gl_max_abs"})


def _bars(metric: str, label: str) -> Chart:
    fields = {"value": f"{metric}/{'median' if metric == 'warp_time' else 'mean'}", "p95": f"{metric}/p95"}
    return Chart(lambda rows: [r for r in wide(rows, ("scene", "system"), fields) if r["value"] is not None],
                 "scene", series="{system}", kind="bar", ylabel=label,
                 tip="{system}, {scene}: {value:.4g}[[, p95 {p95:.4g}]]")  # fmt: skip


PARTS = (
    Figure(
        "warp",
        (
            _bars("warp_time", "warp time per frame [ms] (median)"),
            _bars("cpu_percent", "process CPU [% of one core]"),
            _bars("ssim", "SSIM of warped GI vs GT"),
        ),
        title="Pixel-level vs structure-aware 3D image warping (CPU, one process)",
    ),
    Table(
        _costs,
        (
            Column("scene", "{scene}"),
            Column("warp", "{system}"),
            Column("time per frame ms (median, p95)", "{median:.2f} ({p95:.2f})"),
            Column("CPU % of one core (mean)", "{cpu:.0f}"),
            Column("SSIM vs GT (mean)", "{ssim:.3f}"),
        ),
    ),
    Table(
        lambda rows: wide(rows, ("scene",), {"time": "time_ratio", "cpu": "cpu_ratio"}),
        (
            Column("scene", "{scene}"),
            Column("pixel / structure time (median)", "{time:.2f}×"),
            Column("pixel / structure CPU (mean)", "{cpu:.2f}×"),
        ),
    ),
    Table(
        _backends,
        (
            Column("scene", "{scene}"),
            Column("warp", "{system}"),
            Column("frame ms, numpy (median)", "{numpy:.2f}"),
            Column("frame ms, gl shaders (median)", "{gl:.2f}"),
            Column("gl / numpy", "{ratio:.2f}×"),
            Column("max abs gl − numpy, warped map", "{diff:.2g}"),
        ),
        title="Warp backends (--warp-backend): a whole frame, DI and the warp's pass, the warp and eq. 1",
    ),
)


BENCH = Bench(
    "warp",
    WarpBenchConfig,
    measure,
    help="Fig. 7: CPU time, CPU load, memory and SSIM of pixel-level vs structure-aware warping.",
    dashboard=Section("fig7", "Fig. 7: cost of warping", 50),
    readme=Block("Cost of warping, Fig. 7", 60),
    parts=PARTS,
    needs=("warp_time",),
)
