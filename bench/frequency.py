"""`bench frequency` (paper Table 3): GI-map period k against frame rate and quality, with and without
warping, for both compositions.

Each configuration runs the real client loop (:func:`gigan_local.client.run_frames`) along the scene's
camera path (``orbit_frames`` frames per full orbit) with a new GI map every k frames. Frame rate: the
median per-frame client work plus the mean cost of one GI map spread over its k frames
(:func:`gigan_local.client.amortized_fps`); the GI-map cost is whatever the configured source costs --
the generator's inference (``gi_source = "model"``) or, by default, the path-traced GT stand-in, which is
far slower than a network -- unless ``inference_ms`` replaces it with a given inference time. Quality:
SSIM/PSNR of the composed frame against the path-traced GT at the local camera every ``gt_every`` frames,
averaged. GI maps and GT renders are cached across configurations, so every configuration sees the same
maps and the same references.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from gicore.results import Results

LABELS = {"structure": "structure-aware", "pixel": "pixel-level", "none": "no warping"}


@dataclass(frozen=True)
class FrequencyConfig:
    """The parameter grid of one run."""

    scene: str = "lung_plane"
    resolution: int = 256
    ks: tuple[int, ...] = (1, 10, 20, 30, 60)
    frames: int = 120
    warps: tuple[str, ...] = ("structure", "pixel", "none")
    compositions: tuple[str, ...] = ("blend", "residual")
    tau: float = 0.0
    gt_every: int = 4
    orbit_frames: int = 300
    spp: int = 64
    denoise: bool = True
    gi_source: str = "gt"
    model: Path | None = None
    #: When set, the cost of one GI map in the fps (ms) instead of the source's measured cost.
    inference_ms: float | None = None

    @classmethod
    def quick(cls) -> "FrequencyConfig":
        return cls(frames=60, gt_every=6, spp=16)


def run(cfg: FrequencyConfig, out: Path, seed: int = 0) -> Path:
    from gicore.render import Renderer
    from gicore.scene import load_scene
    from gigan_local.client import ClientConfig, amortized_fps, run_frames

    res = Results("frequency", out, seed, settings=cfg.__dict__)
    spec = load_scene(cfg.scene)
    renderer = Renderer(spec, cfg.resolution)
    cache: dict = {}
    base = ClientConfig(scene=cfg.scene, frames=cfg.frames, resolution=cfg.resolution, orbit_frames=cfg.orbit_frames, tau=cfg.tau, gi_source=cfg.gi_source, model=cfg.model, spp=cfg.spp, denoise=cfg.denoise, gt_every=cfg.gt_every, seed=seed)
    for k in cfg.ks:
        for warp in cfg.warps:
            for composition in cfg.compositions:
                client = replace(base, every=k, warp=warp, composition=composition)
                rows = run_frames(client, renderer, cache)
                fps = amortized_fps(rows, k)
                gi_ms = cfg.inference_ms if cfg.inference_ms is not None else fps["gi_ms"]
                scored = [r for r in rows if r["ssim"] != ""]
                config = {"k": k, "composition": composition, "tau": cfg.tau, "gi_source": cfg.gi_source, "resolution": cfg.resolution, "frames": cfg.frames, "spp": cfg.spp, "orbit_frames": cfg.orbit_frames}

                def add(metric: str, value: float, unit: str, stat: str = "value") -> None:
                    res.add(system=LABELS[warp], scene=spec.name, metric=metric, value=value, unit=unit, stat=stat, **config)

                add("fps", 1000.0 / (fps["local_ms"] + gi_ms / k), "1/s")
                add("frame_time", fps["local_ms"], "ms", "median")
                add("gi_time", gi_ms, "ms", "mean" if cfg.inference_ms is None else "given")
                add("ssim", float(np.mean([r["ssim"] for r in scored])), "1", "mean")
                add("psnr", float(np.mean([r["psnr"] for r in scored if np.isfinite(r["psnr"])])), "dB", "mean")
                add("valid_fraction", float(np.mean([r["valid_frac"] for r in rows])), "1", "mean")
    path = res.write()
    plot(path, out / "frequency.png")
    (out / "frequency_table.md").write_text(table(path))
    return path


def table(csv_path: Path) -> str:
    """Table 3 from the CSV, one block per composition: k, fps (structure-aware), SSIM per warp."""
    from gicore.results import read_rows

    rows = read_rows(csv_path)
    systems = list(dict.fromkeys(r["system"] for r in rows))
    lines = []
    for composition in dict.fromkeys(r["config"]["composition"] for r in rows):
        sel = [r for r in rows if r["config"]["composition"] == composition]
        lines += [f"### composition: {composition}", "", "| k | " + " | ".join(f"fps ({s})" for s in systems) + " | " + " | ".join(f"SSIM ({s})" for s in systems) + " |", "|---" * (1 + 2 * len(systems)) + "|"]
        for k in sorted({r["config"]["k"] for r in sel}):

            def get(system: str, metric: str) -> float:
                return next((r["value"] for r in sel if (r["system"], r["metric"], r["config"]["k"]) == (system, metric, k)), float("nan"))

            lines.append(f"| {k} | " + " | ".join(f"{get(s, 'fps'):.1f}" for s in systems) + " | " + " | ".join(f"{get(s, 'ssim'):.3f}" for s in systems) + " |")
        lines.append("")
    return "\n".join(lines)


def plot(csv_path: Path, png: Path) -> None:
    """Frame rate and SSIM against the GI-map period k, per warp and composition."""
    from gicore.plotting import plt, save, ticker

    from gicore.results import read_rows

    rows = read_rows(csv_path)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for system in dict.fromkeys(r["system"] for r in rows):
        for composition, style in (("blend", "-o"), ("residual", "--s")):
            for ax, metric in zip(axes, ("fps", "ssim")):
                pts = sorted((r["config"]["k"], r["value"]) for r in rows if r["system"] == system and r["metric"] == metric and r["config"]["composition"] == composition)
                if pts:
                    ax.plot(*zip(*pts), style, ms=4, label=f"{system} ({composition})")
    for ax, label in zip(axes, ("frames per second (GI cost amortised over k)", "mean SSIM vs path-traced GT")):
        ax.set_xlabel("GI-map period k [frames]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].yaxis.set_major_formatter(ticker.ScalarFormatter())
    axes[0].yaxis.set_minor_formatter(ticker.NullFormatter())
    axes[1].legend(fontsize=7)
    fig.suptitle("Inference frequency vs system performance (Table 3)")
    save(fig, png)
