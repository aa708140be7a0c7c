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
from functools import partial
from typing import Any

import numpy as np

from bench.runner import Bench
from gicore import option_groups
from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.geometry import scene_objects
from gicore.options import RESOLUTION
from gicore.paths import camera_path, light_position
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, flat, matches, unique
from gicore.results import Results
from gicore.run_config import RENDERERS
from gicore.scene import SceneSpec, builtin_scenes, load_scene
from gicore.timing import time_repeats

#: The timed passes, in plot order.
PASSES = ("di_1spp", "gbuffers", "di_plus_gbuffers", "gt_64spp", "gt_64spp_oidn", "gt_256spp")
#: The clients' per-frame raster passes, timed on both renderers (see the module docstring).
CLIENT_PASSES = ("gi_camera", "local_di", "local_di_uv", "local_di_mask")
#: The views whose ``lod = auto`` level and its G-buffer error are reported: the GI camera's and the local
#: camera's under the model-input bound, and the local camera's under the bound of passes that are only shown.
LOD_VIEWS = {"gi": "gi views", "local": "local views", "local_shown": "local views, shown passes"}
#: GL levels of detail timed: full detail, and the clients' (``gicore.run_config.CLIENT_LOD``).
GL_LODS = ("full", "auto")
#: Suffix of the metric of a GL pass's draw calls alone, timed on the GPU by a GL timer query (the pass's metric
#: is its wall time, read-back to host memory included).
GPU_DRAW = "_gpu_draw"


@dataclass(frozen=True)
class RenderBenchConfig:
    """Which scenes to time, and how often."""

    scenes: tuple[str, ...] = option_groups.scenes(tuple(builtin_scenes()))
    resolution: int = option_groups.resolution()
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
    from gigan_local.warp import bind_coordinates

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

    bind_coordinates(renderer, gi[0])  # once per map, as the warp binds it, not per frame
    return {"gi_camera": gi_camera, "local_di": shown(None), "local_di_uv": shown("uv"), "local_di_mask": shown("mask")}


def _lod_rows(res: Results, gl: Any, spec: SceneSpec, resolution: int, seed: int, config: dict[str, Any]) -> None:
    """For ``lod = auto``: the level each GI and local view of the timed path draws (:data:`LOD_VIEWS`: at the
    local views also the shown passes' level) and its G-buffer error against full detail at that view (mean and
    max over the views: :meth:`gicore.gl.GLRenderer.level_error`)."""
    from gicore.gl.lod import LOD_CHANNELS

    local = camera_path(spec, 8, seed=seed, fov=spec.camera.local_fov, resolution=resolution)
    gi = [c.with_fov(spec.camera.gi_fov) for c in local]
    for view, cams, shown in (("gi", gi, False), ("local", local, False), ("local_shown", local, True)):
        levels, errors = zip(*(gl.level_error(cam, shown) for cam in cams))
        for stat, fn in (("mean", np.mean), ("max", np.max)):
            add = partial(res.add, system="gl", scene=spec.name, unit="1", stat=stat, view=view, **config)
            add(metric="lod_level", value=float(fn(levels)))
            for channel in LOD_CHANNELS:
                add(metric=f"lod_error_{channel}", value=float(fn([e[channel] for e in errors])))


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
                            gpu.append(renderer.gpu_draw_ms(fns[stage]) / 1e3)
                for (system, extra, _), mine, gpu in zip(renderers, samples, gpu_samples):
                    timing = partial(res.add_timing, system=system, scene=spec.name, resolution=resolution,
                                     pass_set="client", **extra)  # fmt: skip
                    timing(metric=stage, samples_s=mine)
                    if gpu:
                        timing(metric=f"{stage}{GPU_DRAW}", samples_s=gpu)
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


# -- what it shows ------------------------------------------------------------------------------------------
def client_rows(rows: Rows) -> list[dict]:
    """Per scene, resolution and client pass: median ms on GL (full, auto: wall, gl / mitsuba, GPU draw) and
    on Mitsuba; each row also holds the level lod auto drew at each view and its G-buffer error."""
    client = [r for r in rows if r["config"].get("pass_set") == "client"]

    def get(scene: str, resolution: int, system: str, metric: str, stat: str, **config: Any) -> float | None:
        where = (scene, system, resolution)
        found = (r for r in client if (r["scene"], r["system"], r["config"]["resolution"]) == where)
        return next((r["value"] for r in found if matches(r, metric, stat, **config)), None)

    out = []
    for scene, resolution in unique((r["scene"], r["config"]["resolution"]) for r in client):
        lod = {}
        for view in LOD_VIEWS:
            for name, metric in [("level", "lod_level")] + [(c, f"lod_error_{c}") for c in LOD_ERRORS]:
                for stat, suffix in (("mean", ""), ("max", "_max")):
                    lod[f"{name}_{view}{suffix}"] = get(scene, resolution, "gl", metric, stat, lod="auto", view=view)
        for stage in CLIENT_PASSES:
            row = {"scene": scene, "resolution": resolution, "stage": stage, **lod}
            row["mitsuba"] = get(scene, resolution, "mitsuba", stage, "median")
            for level in GL_LODS:
                row[f"{level}"] = get(scene, resolution, "gl", stage, "median", lod=level)
                row[f"{level}_ratio"] = get(scene, resolution, "gl/mitsuba", stage, "ratio", lod=level)
                row[f"{level}_draw"] = get(scene, resolution, "gl", f"{stage}{GPU_DRAW}", "median", lod=level)
            out.append(row)
    return out


def _pass_bars(rows: Rows) -> list[dict]:
    """Mitsuba's passes per scene (labelled with its triangles)."""
    triangles = {r["scene"]: int(r["value"]) for r in rows if r["metric"] == "triangles"}
    return [
        flat(r) | {"label": f"{r['scene']}\n{triangles.get(r['scene'], 0):,} triangles"}
        for r in rows
        if r["system"] == "mitsuba" and r["config"].get("pass_set") != "client" and r["metric"] in PASSES
        and r["stat"] == "median"
    ]  # fmt: skip


def _passes_title(rows: Rows) -> str:
    mitsuba = _pass_bars(rows)
    return f"Render passes at {mitsuba[0].get('resolution', '?')}² (Mitsuba {mitsuba[0].get('variant', '')})"


LOD_ERRORS = ("normal", "depth", "coverage")
LOD_NOTE = "\n\n".join(
    f"lod auto at the {label}: level {{level_{v}:.1f}} on average (max {{level_{v}_max:.0f}}); G-buffer error against "
    "full detail: " + ", ".join(f"{c} {{{c}_{v}:.1e}} (max {{{c}_{v}_max:.1e}})" for c in LOD_ERRORS) + "."
    for v, label in LOD_VIEWS.items()
)
PARTS = (
    Table(
        client_rows,
        (
            Column("pass", "{stage}"),
            Column("gl, full detail", "{full:.1f} ({full_ratio:.2f})"),
            Column("GPU draw", "{full_draw:.2f}"),
            Column("gl, lod auto", "{auto:.1f} ({auto_ratio:.2f})"),
            Column("GPU draw", "{auto_draw:.2f}"),
            Column("mitsuba", "{mitsuba:.1f}"),
        ),
        title="Client raster passes: OpenGL beside Mitsuba",
        caption="Median ms per pass, read-back to host memory included (gl / mitsuba in brackets); GPU draw: the "
        "pass's draw calls alone (its shadow map included), timed on the GPU by a GL timer query.",
        group="{scene}, {resolution}²",
        group_note=LOD_NOTE,
    ),
    Figure(
        "render",
        (
            Chart(
                _pass_bars,
                "label",
                series="{metric}",
                kind="bar",
                ylog=True,
                title=_passes_title,
                ylabel="time per frame [ms] (median)",
                tip="{metric}, {scene}: {value:.4g} ms",
            ),
        ),  # fmt: skip
    ),
)


BENCH = Bench(
    "render",
    RenderBenchConfig,
    measure,
    help="Per-pass render times (DI, G-buffers, GT with/without OIDN) and triangle counts per scene; the clients' "
    "raster passes (GI camera, local DI, uv, depth) on OpenGL (full detail and lod auto) beside Mitsuba.",
    parts=PARTS,
)
