"""`bench convergence`: error of the path-traced GT against render time, with and without OIDN.

For each scene, one frame of its fly-through is rendered at a range of spp and compared with a
high-spp reference (different seed, no denoising) on tone-mapped images. Render times are medians of
repeats after a warm-up; the OIDN variant's time includes its G-buffer pass and the denoiser.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.runner import Bench
from gicore.metrics import all_metrics
from gicore.paths import camera_path, light_position
from gicore.results import Results, read_rows
from gicore.scene import builtin_scenes, load_scene
from gicore.timing import time_repeats
from gicore.tonemap import tonemap


@dataclass(frozen=True)
class ConvergenceConfig:
    """The parameter grid of one run."""

    #: Scene names or spec files.
    scenes: tuple[str, ...] = tuple(builtin_scenes())
    #: Square resolution in pixels.
    resolution: int = 256
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
        reference = tonemap(renderer.render_gt(camera, light, spp=cfg.reference_spp, seed=seed + 10_000))
        for spp in cfg.spps:

            def raw(spp: int = spp) -> np.ndarray:
                return renderer.render_gt(camera, light, spp=spp, seed=seed)

            def denoised(spp: int = spp) -> np.ndarray:  # the guide pass is part of its cost
                return renderer.denoise(raw(spp), renderer.render_gbuffers(camera, seed=seed))

            for system, render in (("path", raw), ("path+oidn", denoised)):
                samples, image = time_repeats(render, cfg.repeats)
                res.add_timing(
                    system=system,
                    scene=name,
                    metric="render_time",
                    samples_s=samples,
                    spp=spp,
                    resolution=cfg.resolution,
                )
                for metric, value in all_metrics(tonemap(image), reference).items():
                    res.add(
                        system=system,
                        scene=name,
                        metric=metric,
                        value=value,
                        unit="dB" if metric == "psnr" else "1",
                        spp=spp,
                        resolution=cfg.resolution,
                    )


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """RMSE and SSIM against median render time, one line per scene and denoiser setting."""
    from gicore.plotting import plt, save, ticker

    rows = read_rows(csv_path)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    keys = sorted({(r["scene"], r["system"]) for r in rows})
    for scene, system in keys:
        sel = [r for r in rows if r["scene"] == scene and r["system"] == system]
        times = {r["config"]["spp"]: r["value"] for r in sel if r["metric"] == "render_time" and r["stat"] == "median"}
        for ax, metric in zip(axes, ("rmse", "ssim")):
            vals = {r["config"]["spp"]: r["value"] for r in sel if r["metric"] == metric}
            spps = sorted(vals)
            ax.plot(
                [times[s] for s in spps],
                [vals[s] for s in spps],
                "-o" if system == "path" else "--s",
                label=f"{scene} ({system})",
                ms=4,
            )
            for s in spps:
                ax.annotate(str(s), (times[s], vals[s]), fontsize=6, alpha=0.6)
    for ax, metric in zip(axes, ("RMSE (tone-mapped)", "SSIM")):
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_xlabel("median render time per frame [ms]")
        ax.set_ylabel(metric)
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].yaxis.set_minor_formatter(ticker.NullFormatter())
    axes[1].legend(fontsize=6, loc="lower right")
    fig.suptitle("GT convergence: error vs render time (labels: spp; reference: high-spp path tracing)")
    return [save(fig, out_dir / "convergence.png")]


BENCH = Bench(
    "convergence",
    ConvergenceConfig,
    measure,
    plot,
    help="GT error (RMSE/SSIM against a high-spp reference) against render time, with and without OIDN.",
)
