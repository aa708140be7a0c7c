"""`bench render`: per-pass render cost of each scene (SPEC §3 numbers, measured here).

Passes: DI at 1 spp, the G-buffer (AOV) pass, DI + G-buffers together (what a client renders per
frame), GT at 64 spp, GT at 64 spp + OIDN (incl. its G-buffer guide pass) and GT at 256 spp. Also the
scene's triangle count. Medians and p95 over repeats after a warm-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from gicore.results import Results
from gicore.timing import time_repeats
from gicore.paths import camera_path, light_position
from gicore.scene import builtin_scenes, load_scene


@dataclass(frozen=True)
class RenderBenchConfig:
    scenes: tuple[str, ...] = tuple(builtin_scenes())
    resolution: int = 256
    repeats: int = 7
    gt_repeats: int = 3

    @classmethod
    def quick(cls) -> "RenderBenchConfig":
        return cls(scenes=("lung_plane",), resolution=128, repeats=5, gt_repeats=2)


def run(cfg: RenderBenchConfig, out: Path, seed: int = 0) -> Path:
    from gicore.render import VARIANT, Renderer

    res = Results("render", out, seed, settings=cfg.__dict__ | {"variant": VARIANT})
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
        for stage, (fn, repeats) in passes.items():
            samples, _ = time_repeats(fn, repeats, warmup=2)
            res.add_timing(system="mitsuba", scene=name, metric=stage, samples_s=samples, resolution=cfg.resolution, variant=VARIANT)
    return res.write()
