"""`bench render`: per-pass render cost of each scene, measured here.

Mitsuba (``system = mitsuba``, at ``resolution``): DI at 1 spp, the G-buffer (AOV) pass, DI + G-buffers
together, GT at 64 spp, GT at 64 spp + OIDN (incl. its G-buffer guide pass) and GT at 256 spp. Also the
scene's triangle count. Medians and p95 over repeats after a warm-up; the plot shows them per scene.

The clients' raster passes (:data:`CLIENT_PASSES`, at each of ``gl_resolutions``), as a client runs them
frame after frame (the camera moves along the scene's path, the light along its schedule, so with a moving
light every GL DI pass here redraws its shadow map; in a client the frame's first DI pass does):
``gi_camera`` (DI + centre-sampled G-buffers at the GI camera: GIGAN's generator input), ``local_di`` (DI at
the local camera: a frame before any map arrived), ``local_di_uv`` (DI + the structure-aware warp's pass,
coordinates projected from a GI camera: GIGAN's shown frame) and ``local_di_mask`` (DI + the pixel-level
warp's surface mask: cloud baking's shown frame), each of the last two as the clients render it
(``render_di_raster``: one pass into several render targets on GL, two passes on Mitsuba). Each on OpenGL
(``system = gl``, at ``lod`` ``full`` and at the clients' ``auto``; :class:`gicore.gl.GLRenderer`) and on
Mitsuba (``system = mitsuba``: the centre-sampled passes a ``--renderer mitsuba`` client runs), side by
side in one run, one repeat of each renderer in turn (``stat = ratio`` rows: gl median over Mitsuba
median). For ``lod = auto``: the level each view drew (``lod_level``) and what it cost against full detail
at that view, per G-buffer channel (``lod_error_*``, :func:`gicore.gl.lod.lod_errors`; ``view = gi`` or
``local``). Where no GL context opens the GL passes are left out after one warning. ``--renderers gl`` times
the GL passes alone (no Mitsuba import: what a GPU machine without Mitsuba can run).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.runner import Bench
from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.geometry import scene_objects
from gicore.loop import RENDERERS
from gicore.options import RESOLUTION
from gicore.paths import camera_path, light_position
from gicore.results import Results, read_rows
from gicore.scene import SceneSpec, builtin_scenes, load_scene
from gicore.timing import time_repeats

#: The timed passes, in plot order.
PASSES = ("di_1spp", "gbuffers", "di_plus_gbuffers", "gt_64spp", "gt_64spp_oidn", "gt_256spp")
#: The clients' per-frame raster passes, timed on both renderers (see the module docstring).
CLIENT_PASSES = ("gi_camera", "local_di", "local_di_uv", "local_di_mask")
#: The views whose ``lod = auto`` level and its G-buffer error are reported: the GI camera's and the local
#: camera's under the model-input bound, and the local camera's under the bound of passes that are only shown.
LOD_VIEWS = {"gi": "gi views", "local": "local views", "local_shown": "local views, shown passes"}
#: GL levels of detail timed: full detail, and the clients' (``gicore.loop.CLIENT_LOD``).
GL_LODS = ("full", "auto")
#: Suffix of the metric of a GL pass's draw calls alone, timed on the GPU by a GL timer query (the pass's metric
#: is its wall time, read-back to host memory included).
GPU_DRAW = "_gpu_draw"


@dataclass(frozen=True)
class RenderBenchConfig:
    """Which scenes to time, and how often."""

    #: Scene names or spec files.
    scenes: tuple[str, ...] = tuple(builtin_scenes())
    #: Square resolution in pixels.
    resolution: int = 256
    #: Timed repeats of the cheap passes (DI, G-buffers), after two warm-ups.
    repeats: int = 7
    #: Timed repeats of the path-traced GT passes, after two warm-ups.
    gt_repeats: int = 3
    #: Square resolutions of the clients' raster passes on GL and Mitsuba (none: leave them out).
    gl_resolutions: tuple[int, ...] = field(default=(256, 512), metadata={**RESOLUTION, "min_len": 0})
    #: Timed repeats of each client raster pass, after two warm-ups.
    gl_repeats: int = 15
    #: Renderers timed: mitsuba (its passes above; with gl, the client passes beside GL's with gl / mitsuba
    #: ratios) and/or gl (the client passes). ``gl`` alone needs no Mitsuba: a GPU machine's GL passes by themselves.
    renderers: tuple[str, ...] = ("gl", "mitsuba")

    def __post_init__(self) -> None:
        for name in self.renderers:
            if name not in RENDERERS:
                raise UserError(f"--renderers {name!r} is not a renderer", f"use some of {', '.join(RENDERERS)}")
        if not self.renderers or len(set(self.renderers)) != len(self.renderers):
            raise UserError(f"--renderers {','.join(self.renderers)!r} must name each renderer once", "e.g. gl,mitsuba")
        if self.renderers == ("gl",) and not self.gl_resolutions:
            raise UserError("--renderers gl with no --gl-resolutions times nothing", "give a resolution, e.g. 256")

    @classmethod
    def quick(cls) -> RenderBenchConfig:
        return cls(scenes=("lung_plane",), resolution=128, repeats=5, gt_repeats=2, gl_resolutions=(256,), gl_repeats=7)


def measure(cfg: RenderBenchConfig, res: Results) -> None:
    for name in cfg.scenes:
        spec = load_scene(name)
        triangles = sum(o.mesh.n_triangles for o in scene_objects(spec))
        res.add(system="scene", scene=spec.name, metric="triangles", value=triangles, unit="count")
    if "mitsuba" in cfg.renderers:
        measure_mitsuba_passes(cfg, res)
    if cfg.gl_resolutions and "gl" in cfg.renderers:
        measure_client_passes(cfg, res)


def measure_mitsuba_passes(cfg: RenderBenchConfig, res: Results) -> None:
    """Mitsuba's passes (:data:`PASSES`) per scene at ``cfg.resolution``."""
    from gicore.render import VARIANT, Renderer

    seed = res.seed
    for name in cfg.scenes:
        spec = load_scene(name)
        renderer = Renderer(spec, cfg.resolution)
        cams = camera_path(spec, 8, seed=seed, resolution=cfg.resolution)
        light = light_position(spec, 0)
        # Alternate cameras so every timed call really moves the sensor (as in an animation).
        state = {"i": 0}

        def next_cam():
            state["i"] += 1
            return cams[state["i"] % len(cams)]

        def gt_oidn(spp: int = 64):
            cam = next_cam()
            return renderer.denoise(renderer.render_gt(cam, light, spp=spp, seed=seed), renderer.render_gbuffers(cam))

        passes = {
            "di_1spp": (lambda: renderer.render_di(next_cam(), light), cfg.repeats),
            "gbuffers": (lambda: renderer.render_gbuffers(next_cam()), cfg.repeats),
            "di_plus_gbuffers": (lambda: renderer.render_di_gbuffers(next_cam(), light), cfg.repeats),
            "gt_64spp": (lambda: renderer.render_gt(next_cam(), light, spp=64, seed=seed), cfg.gt_repeats),
            "gt_64spp_oidn": (gt_oidn, cfg.gt_repeats),
            "gt_256spp": (lambda: renderer.render_gt(next_cam(), light, spp=256, seed=seed), cfg.gt_repeats),
        }
        for stage in PASSES:
            fn, repeats = passes[stage]
            samples, _ = time_repeats(fn, repeats, warmup=2)
            res.add_timing(
                system="mitsuba",
                scene=spec.name,
                metric=stage,
                samples_s=samples,
                resolution=cfg.resolution,
                variant=VARIANT,
            )


# -- the clients' raster passes, GL beside Mitsuba ---------------------------------------------------------
def _client_passes(renderer: Any, spec: SceneSpec, resolution: int, seed: int) -> dict[str, Callable[[], Any]]:
    """The clients' raster passes on ``renderer`` (GL or Mitsuba), each moving to the next frame's cameras
    and light on every call, as a client does."""
    from gigan_local.warp import clip_xy

    n = 8
    local = camera_path(spec, n, seed=seed, fov=spec.camera.local_fov, resolution=resolution)
    gi = [c.with_fov(spec.camera.gi_fov) for c in local]
    frame = {"i": 0}

    def views() -> tuple[Camera, Camera, tuple]:
        frame["i"] += 1
        i = frame["i"]
        return local[i % n], gi[i % n], light_position(spec, i)

    def gi_camera():
        _, cam, light = views()
        return renderer.render_di_gbuffers(cam, light, centre=True)

    def shown(raster: str | None) -> Callable[[], Any]:
        def render():
            cam, _, light = views()
            return renderer.render_di_raster(cam, light, raster)

        return render

    project = getattr(renderer, "set_texcoord_projection", None)
    if project is not None:  # GL: the vertex shader projects from the bound GI camera (as the warp binds it)
        project(gi[0])
    else:  # Mitsuba: per-vertex coordinates uploaded once per map (the warp's bind), not per frame
        for obj in renderer.objects:
            renderer.set_texcoords(obj.name, clip_xy(gi[0], obj.mesh.vertices))
    return {"gi_camera": gi_camera, "local_di": shown(None), "local_di_uv": shown("uv"), "local_di_mask": shown("mask")}


def _lod_rows(res: Results, gl: Any, spec: SceneSpec, resolution: int, seed: int, config: dict[str, Any]) -> None:
    """For ``lod = auto``: the level each GI and local view of the timed path draws (:data:`LOD_VIEWS`: at the
    local views also the shown passes' level) and its G-buffer error against full detail at that view (mean and
    max over the views)."""
    from gicore.gl.lod import LOD_CHANNELS, lod_errors

    local = camera_path(spec, 8, seed=seed, fov=spec.camera.local_fov, resolution=resolution)
    gi = [c.with_fov(spec.camera.gi_fov) for c in local]
    for view, cams, shown in (("gi", gi, False), ("local", local, False), ("local_shown", local, True)):
        levels, errors = [], []
        for cam in cams:
            gl.lod = level = gl.level_for(cam, shown=shown)
            levels.append(level)
            at_level = gl.render_gbuffers(cam)
            gl.lod = 0
            errors.append(lod_errors(at_level, gl.render_gbuffers(cam)))
            gl.lod = "auto"
        where = config | {"view": view}
        for stat, fn in (("mean", np.mean), ("max", np.max)):
            res.add(system="gl", scene=spec.name, metric="lod_level", value=float(fn(levels)), unit="1", stat=stat,
                    **where)  # fmt: skip
            for channel in LOD_CHANNELS:
                value = float(fn([e[channel] for e in errors]))
                res.add(system="gl", scene=spec.name, metric=f"lod_error_{channel}", value=value, unit="1", stat=stat,
                        **where)  # fmt: skip


def measure_client_passes(cfg: RenderBenchConfig, res: Results) -> None:
    """The clients' raster passes on GL (lod full and auto) and, where ``cfg.renderers`` names it, on Mitsuba,
    per scene and resolution."""
    from gicore.gl import GLRenderer, gl_available

    ok, info = gl_available()
    if not ok:
        print(f"warning: renderer gl is unavailable, leaving out the GL passes: {info}", file=sys.stderr, flush=True)
        return
    res.settings["gl_renderer"] = info
    with_mitsuba = "mitsuba" in cfg.renderers
    for name in cfg.scenes:
        spec = load_scene(name)
        for resolution in cfg.gl_resolutions:
            medians: dict[tuple[str, str, str], float] = {}
            renderers: list[tuple[str, dict[str, Any], Any]] = [
                ("gl", {"lod": lod}, GLRenderer(spec, resolution, lod=lod)) for lod in GL_LODS
            ]
            if with_mitsuba:
                from gicore.render import VARIANT, Renderer

                renderers.append(("mitsuba", {"variant": VARIANT}, Renderer(spec, resolution)))
            passes = [_client_passes(renderer, spec, resolution, res.seed) for _, _, renderer in renderers]
            for stage in CLIENT_PASSES:
                # one repeat of each renderer in turn, so that a shared machine's changing load falls on all alike
                samples: list[list[float]] = [[] for _ in renderers]
                gpu_samples: list[list[float]] = [[] for _ in renderers]
                for fns in passes:
                    time_repeats(fns[stage], 1, warmup=1)
                for _ in range(cfg.gl_repeats):
                    for mine, gpu, fns, (system, _, renderer) in zip(samples, gpu_samples, passes, renderers):
                        mine += time_repeats(fns[stage], 1, warmup=0)[0]
                        if system == "gl":  # a call of its own: reading the timer query waits for the GPU
                            renderer.gpu_timing, renderer.draw_ms = True, None
                            try:
                                fns[stage]()
                            finally:
                                renderer.gpu_timing = False
                            gpu.append(renderer.draw_ms / 1e3)
                for (system, extra, _), mine, gpu in zip(renderers, samples, gpu_samples):
                    config = {"resolution": resolution, "pass_set": "client"} | extra
                    res.add_timing(system=system, scene=spec.name, metric=stage, samples_s=mine, **config)
                    if gpu:
                        res.add_timing(
                            system=system, scene=spec.name, metric=f"{stage}{GPU_DRAW}", samples_s=gpu, **config
                        )
                    medians[system, extra.get("lod", ""), stage] = float(np.median(mine))
            for _, extra, renderer in renderers:
                if extra.get("lod") == "auto":
                    config = {"resolution": resolution, "pass_set": "client"} | extra
                    _lod_rows(res, renderer, spec, resolution, res.seed, config)
            for lod in GL_LODS if with_mitsuba else ():
                for stage in CLIENT_PASSES:
                    ratio = medians["gl", lod, stage] / medians["mitsuba", "", stage]
                    config = {"resolution": resolution, "pass_set": "client", "lod": lod}
                    res.add(
                        system="gl/mitsuba",
                        scene=spec.name,
                        metric=stage,
                        value=ratio,
                        unit="1",
                        stat="ratio",
                        **config,
                    )


def client_table(rows: list[dict]) -> str:
    """The clients' raster passes per scene and resolution: median ms on GL (full, auto; wall and GPU draw) and
    Mitsuba, gl / mitsuba, and the level auto drew with its G-buffer error."""

    def get(scene: str, system: str, metric: str, stat: str, **config: Any) -> float | None:
        return next(
            (
                r["value"]
                for r in rows
                if (r["scene"], r["system"], r["metric"], r["stat"]) == (scene, system, metric, stat)
                and r["config"].get("pass_set") == "client"
                and all(r["config"].get(k) == v for k, v in config.items())
            ),
            None,
        )

    def ms(value: float | None, spec: str = ".1f") -> str:
        return "—" if value is None else format(value, spec)

    keys = list(dict.fromkeys((r["scene"], r["config"]["resolution"]) for r in rows if r["config"].get("pass_set")))
    lines = [
        "## Client raster passes: OpenGL beside Mitsuba",
        "",
        "Median ms per pass, read-back to host memory included (gl / mitsuba in brackets); GPU draw: the pass's",
        "draw calls alone (its shadow map included), timed on the GPU by a GL timer query.",
        "",
    ]
    for scene, resolution in keys:
        at = {"resolution": resolution}
        lines += [
            f"### {scene}, {resolution}²",
            "",
            "| pass | gl, full detail | GPU draw | gl, lod auto | GPU draw | mitsuba |",
            "|---|---|---|---|---|---|",
        ]
        for stage in CLIENT_PASSES:
            cells = []
            for lod in GL_LODS:
                median, ratio, draw = (
                    get(scene, "gl", stage, "median", lod=lod, **at),
                    get(scene, "gl/mitsuba", stage, "ratio", lod=lod, **at),
                    get(scene, "gl", f"{stage}{GPU_DRAW}", "median", lod=lod, **at),
                )
                cells += [f"{ms(median)} ({ms(ratio, '.2f')})", ms(draw, ".2f")]
            mitsuba = ms(get(scene, "mitsuba", stage, "median", **at))
            lines.append(f"| {stage} | " + " | ".join(cells) + f" | {mitsuba} |")
        for view in LOD_VIEWS:
            where = at | {"lod": "auto", "view": view}
            errors = []
            for c in ("normal", "depth", "coverage"):
                mean, top = (get(scene, "gl", f"lod_error_{c}", stat, **where) for stat in ("mean", "max"))
                errors.append(f"{c} {ms(mean, '.1e')} (max {ms(top, '.1e')})")
            level, top = (get(scene, "gl", "lod_level", stat, **where) for stat in ("mean", "max"))
            lines.append(
                f"\nlod auto at the {LOD_VIEWS[view]}: level {ms(level, '.1f')} on average (max {ms(top, '.0f')}); "
                f"G-buffer error against full detail: {', '.join(errors)}."
            )
        lines.append("")
    return "\n".join(lines)


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Median time of each pass per scene (bars, p95 whiskers, log scale: passes span three decades)."""
    from gicore.plotting import plt, save, ticker

    rows = read_rows(csv_path)
    written = []
    if any(r["config"].get("pass_set") == "client" for r in rows):
        md = out_dir / "render_client_passes.md"
        md.write_text(client_table(rows) + "\n")
        written.append(md)
    mitsuba_passes = [r for r in rows if r["system"] == "mitsuba" and r["config"].get("pass_set") != "client"]
    if not mitsuba_passes:  # --renderers gl
        return written
    scenes = list(dict.fromkeys(r["scene"] for r in mitsuba_passes))
    stages = [s for s in PASSES if any(r["metric"] == s for r in mitsuba_passes)]

    def value(scene: str, stage: str, stat: str) -> float:
        return next(
            (r["value"] for r in mitsuba_passes if (r["scene"], r["metric"], r["stat"]) == (scene, stage, stat)),
            float("nan"),
        )

    fig, ax = plt.subplots(figsize=(max(7.0, 1.6 * len(scenes) + 4), 4.2))
    width = 0.8 / len(stages)
    x = np.arange(len(scenes))
    for i, stage in enumerate(stages):
        med = np.array([value(s, stage, "median") for s in scenes])
        p95 = np.array([value(s, stage, "p95") for s in scenes])
        ax.bar(x + (i + 0.5) * width - 0.4, med, width, yerr=[np.zeros_like(med), p95 - med], capsize=2, label=stage)
    triangles = {r["scene"]: int(r["value"]) for r in rows if r["metric"] == "triangles"}
    ax.set_xticks(x, [f"{s}\n{triangles.get(s, 0):,} triangles" for s in scenes], fontsize=7)
    ax.set_yscale("log")
    for axis in (ax.yaxis.set_major_formatter, ax.yaxis.set_minor_formatter):
        axis(ticker.FormatStrFormatter("%g"))
    ax.set_ylabel("time per frame [ms] (median, p95 whisker)")
    ax.grid(axis="y", alpha=0.3, which="both")
    ax.legend(fontsize=7, ncols=2)
    resolution = next((r["config"].get("resolution") for r in mitsuba_passes if r["stat"] == "median"), "?")
    variant = next((r["config"].get("variant") for r in mitsuba_passes if r["stat"] == "median"), "")
    ax.set_title(f"Render passes at {resolution}² (Mitsuba {variant})")
    return [save(fig, out_dir / "render.png"), *written]


BENCH = Bench(
    "render",
    RenderBenchConfig,
    measure,
    plot,
    help="Per-pass render times (DI, G-buffers, GT with/without OIDN) and triangle counts per scene; the clients' "
    "raster passes (GI camera, local DI, uv, depth) on OpenGL (full detail and lod auto) beside Mitsuba.",
)
