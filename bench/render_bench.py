"""`bench render`: per-pass render cost of each scene (SPEC §3 numbers, measured here).

Passes: DI at 1 spp, the G-buffer (AOV) pass, DI + G-buffers together (what a client renders per
frame), GT at 64 spp, GT at 64 spp + OIDN (incl. its G-buffer guide pass) and GT at 256 spp. Also the
scene's triangle count. Medians and p95 over repeats after a warm-up; the plot shows them per scene.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.runner import Bench
from gicore.paths import camera_path, light_position
from gicore.results import Results, read_rows
from gicore.scene import builtin_scenes, load_scene
from gicore.timing import time_repeats

#: The timed passes, in plot order.
PASSES = ("di_1spp", "gbuffers", "di_plus_gbuffers", "gt_64spp", "gt_64spp_oidn", "gt_256spp")


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

    @classmethod
    def quick(cls) -> RenderBenchConfig:
        return cls(scenes=("lung_plane",), resolution=128, repeats=5, gt_repeats=2)


def measure(cfg: RenderBenchConfig, res: Results) -> None:
    from gicore.render import VARIANT, Renderer

    seed = res.seed
    for name in cfg.scenes:
        spec = load_scene(name)
        renderer = Renderer(spec, cfg.resolution)
        triangles = sum(o.mesh.n_triangles for o in renderer.objects)
        res.add(system="scene", scene=name, metric="triangles", value=triangles, unit="count")
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
                scene=name,
                metric=stage,
                samples_s=samples,
                resolution=cfg.resolution,
                variant=VARIANT,
            )


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Median time of each pass per scene (bars, p95 whiskers, log scale: passes span three decades)."""
    from gicore.plotting import plt, save, ticker

    rows = read_rows(csv_path)
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    stages = [s for s in PASSES if any(r["metric"] == s for r in rows)]

    def value(scene: str, stage: str, stat: str) -> float:
        return next(
            (r["value"] for r in rows if (r["scene"], r["metric"], r["stat"]) == (scene, stage, stat)), float("nan")
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
    resolution = next((r["config"].get("resolution") for r in rows if r["stat"] == "median"), "?")
    variant = next((r["config"].get("variant") for r in rows if r["stat"] == "median"), "")
    ax.set_title(f"Render passes at {resolution}² (Mitsuba {variant})")
    return [save(fig, out_dir / "render.png")]


BENCH = Bench(
    "render",
    RenderBenchConfig,
    measure,
    plot,
    help="Per-pass render times (DI, G-buffers, GT with/without OIDN) and triangle counts per scene.",
)
