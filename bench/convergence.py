"""`bench convergence`: error of the path-traced GT against render time, with and without OIDN.

For each scene, one frame of its fly-through is rendered at a range of spp and compared with a
high-spp reference (different seed, no denoising) on tone-mapped images. Render times are medians of
repeats after a warm-up; the OIDN variant's time includes its G-buffer pass and the denoiser.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

from bench.runner import Bench
from gicore import option_groups
from gicore.ground_truth import render_gt
from gicore.metrics import all_metrics
from gicore.paths import camera_path, light_position
from gicore.present.declarations import Chart, Figure, wide
from gicore.results import Results
from gicore.scene import builtin_scenes, load_scene
from gicore.timing import time_repeats
from gicore.tonemap import tonemap


@dataclass(frozen=True)
class ConvergenceConfig:
    """The parameter grid of one run."""

    scenes: tuple[str, ...] = option_groups.scenes(tuple(builtin_scenes()))
    resolution: int = option_groups.resolution()
    #: Samples per pixel of the measured GT renders.
    spps: tuple[int, ...] = (1, 4, 16, 64, 256)
    #: Samples per pixel of the reference (other seed, no denoising).
    reference_spp: int = 4096
    #: Timed repeats per render, after one warm-up.
    repeats: int = 3

    @classmethod
    def quick(cls) -> ConvergenceConfig:
        return cls(
            scenes=("lung_plane", "lung_cornell"), resolution=96, spps=(1, 4, 16, 64), reference_spp=1024, repeats=2
        )


def measure(cfg: ConvergenceConfig, res: Results) -> None:
    from gicore.render import Renderer

    seed = res.seed
    for name in cfg.scenes:
        spec = load_scene(name)
        renderer = Renderer(spec, cfg.resolution)
        camera = camera_path(spec, 1, seed=seed, resolution=cfg.resolution)[0]
        light = light_position(spec, 0)
        reference = tonemap(render_gt(renderer, camera, light, cfg.reference_spp, seed + 10_000, denoise=False))
        for spp in cfg.spps:
            for system, denoise in (("path", False), ("path+oidn", True)):  # OIDN's guide pass is part of its cost
                render = partial(render_gt, renderer, camera, light, spp, seed, denoise)
                samples, image = time_repeats(render, cfg.repeats)
                where = {"system": system, "scene": name, "spp": spp, "resolution": cfg.resolution}
                res.add_timing(metric="render_time", samples_s=samples, **where)
                for metric, value in all_metrics(tonemap(image), reference).items():
                    res.add(metric=metric, value=value, unit="dB" if metric == "psnr" else "1", **where)


def _against_time(metric: str, label: str, log: bool) -> Chart:
    """``metric`` against the median render time, one line per scene and denoiser setting (marks: spp)."""
    fields = {"time": "render_time/median", "value": metric}
    return Chart(lambda rows: wide(rows, ("scene", "system", "spp"), fields), "time", series="{scene} ({system})",
                 xlabel="median render time per frame [ms]", ylabel=label, xlog=True, ylog=log, label="{spp}",
                 tip="{series}, {spp} spp: {time:.4g} ms, " + metric + " {value:.4g}")  # fmt: skip


PARTS = (
    Figure(
        "convergence",
        (_against_time("rmse", "RMSE (tone-mapped)", True), _against_time("ssim", "SSIM", False)),
        title="GT convergence: error vs render time (labels: spp; reference: high-spp path tracing)",
    ),
)


BENCH = Bench(
    "convergence",
    ConvergenceConfig,
    measure,
    help="GT error (RMSE/SSIM against a high-spp reference) against render time, with and without OIDN.",
    parts=PARTS,
)
