"""`bench frequency` (paper Table 3): GI-map period k against frame rate and quality, with and without
warping, for both compositions.

Each configuration runs the shared client loop (:func:`gicore.loop.run_frames`) along the scene's camera
path (``orbit_frames`` frames per full orbit) with a new GI map every k frames, from GIGAN's source
(:mod:`gigan_local.client`) brought to the view by GIGAN's warp, cloud baking's, or none
(:func:`bench.common.make_warp`). Frame rate: the median per-frame client work plus the mean cost of
one GI map spread over its k frames (:func:`gicore.loop.amortized_fps`); the GI-map cost is whatever the
configured source costs -- the generator's inference (``gi_source = "model"``) or, by default, the
path-traced GT stand-in, which is far slower than a network -- unless ``inference_ms`` replaces it with a
given inference time. Quality:
SSIM/PSNR of the composed frame against the path-traced GT at the local camera every ``gt_every`` frames,
averaged. GI maps and GT renders are cached across configurations, so every configuration sees the same
maps and the same references.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from bench.common import WARP_LABELS, WARPS, make_warp
from bench.exported_models import check_model_resolution
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, need, pick
from bench.svg import Point, Series, XYChart
from gicore.blend import COMPOSITIONS
from gicore.results import Results, read_rows
from gigan_local.client import GI_SOURCES
from gigan_local.inference import DEFAULT_MODEL


@dataclass(frozen=True)
class FrequencyConfig:
    """The parameter grid of one run."""

    #: Scene names or spec files.
    scenes: tuple[str, ...] = ("lung_plane",)
    #: Square resolution in pixels.
    resolution: int = 256
    #: GI-map periods k (a new GI map every k frames).
    ks: tuple[int, ...] = (1, 10, 20, 30, 60)
    #: Client frames per configuration.
    frames: int = 120
    #: Warp methods compared.
    warps: tuple[Literal[WARPS], ...] = ("structure", "pixel", "none")
    #: How the GI map and the DI frame are composed.
    compositions: tuple[Literal[COMPOSITIONS], ...] = ("blend", "residual")
    #: Blend threshold of the composition (0: plain blend).
    tau: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})
    #: Score the composed frame against path-traced GT every this many frames.
    gt_every: int = 4
    #: Frames per full orbit of the camera path (360° / orbit_frames per frame).
    orbit_frames: int = 300
    #: Samples per pixel of path-traced GT (the gt GI source and the evaluation GT).
    spp: int = 64
    #: Denoise the path-traced renders with OIDN.
    denoise: bool = True
    #: Where GI maps come from: the path-traced GT stand-in, or the generator (--model).
    gi_source: Literal[GI_SOURCES] = "gt"
    #: ONNX generator for --gi-source model (gigan-export output).
    model: Path = DEFAULT_MODEL
    #: When set, the cost of one GI map in the fps (ms) instead of the source's measured cost.
    inference_ms: float | None = None

    @classmethod
    def quick(cls) -> FrequencyConfig:
        return cls(frames=60, gt_every=6, spp=16)

    def check(self) -> None:
        if self.gi_source == "model":
            check_model_resolution(self.model, self.resolution)


def measure(cfg: FrequencyConfig, res: Results) -> None:
    from gicore.loop import ClientLoop, GroundTruth, LoopConfig, amortized_fps, path_views, run_frames
    from gicore.render import Renderer
    from gicore.scene import load_scene
    from gigan_local.client import ClientConfig, check_denoiser, make_gi_source

    check_denoiser(cfg.denoise)
    for scene in cfg.scenes:
        spec = load_scene(scene)
        renderer = Renderer(spec, cfg.resolution)
        cache: dict = {}  # GI maps and GT renders, shared by every configuration
        client = ClientConfig(
            scene=scene,
            resolution=cfg.resolution,
            gi_source=cfg.gi_source,
            model=cfg.model,
            spp=cfg.spp,
            denoise=cfg.denoise,
            seed=res.seed,
        )
        source = make_gi_source(client, renderer, cache)
        ground_truth = GroundTruth(renderer, cfg.gt_every, cfg.spp, cfg.denoise, res.seed, cache)
        local_fov = spec.camera.local_fov
        views = path_views(spec, cfg.frames, cfg.orbit_frames, res.seed, local_fov, cfg.resolution)
        for k in cfg.ks:
            for warp in cfg.warps:
                for composition in cfg.compositions:
                    gi_fov = (
                        local_fov if warp == "none" else spec.camera.gi_fov
                    )  # pasting needs a map made at the local FOV
                    loop_cfg = LoopConfig(every=k, gi_fov=gi_fov, composition=composition, tau=cfg.tau, seed=res.seed)
                    rows = run_frames(
                        ClientLoop(loop_cfg, renderer, source, make_warp(warp, renderer, composition)),
                        views,
                        ground_truth,
                    )
                    fps = amortized_fps(rows, k)
                    gi_ms = cfg.inference_ms if cfg.inference_ms is not None else fps["gi_ms"]
                    scored = [r for r in rows if r["ssim"] != ""]
                    config = {
                        "k": k,
                        "composition": composition,
                        "tau": cfg.tau,
                        "gi_source": cfg.gi_source,
                        "resolution": cfg.resolution,
                        "frames": cfg.frames,
                        "spp": cfg.spp,
                        "orbit_frames": cfg.orbit_frames,
                    }

                    def add(metric: str, value: float, unit: str, stat: str = "value") -> None:
                        res.add(
                            system=WARP_LABELS[warp],
                            scene=spec.name,
                            metric=metric,
                            value=value,
                            unit=unit,
                            stat=stat,
                            **config,
                        )

                    add("fps", 1000.0 / (fps["local_ms"] + gi_ms / k), "1/s")
                    add("frame_time", fps["local_ms"], "ms", "median")
                    add("gi_time", gi_ms, "ms", "mean" if cfg.inference_ms is None else "given")
                    add("ssim", float(np.mean([r["ssim"] for r in scored])), "1", "mean")
                    add("psnr", float(np.mean([r["psnr"] for r in scored if np.isfinite(r["psnr"])])), "dB", "mean")
                    add("lf_error", float(np.mean([r["lf_error"] for r in scored])), "1", "mean")
                    add("valid_fraction", float(np.mean([r["valid_frac"] for r in rows])), "1", "mean")


def table(rows: Rows) -> str:
    """Table 3 from the CSV's rows, one block per scene and composition: k, then fps and SSIM per warp, and the
    low-frequency error per warp where the CSV has it (CSVs older than the metric do not)."""
    systems = list(dict.fromkeys(r["system"] for r in rows))
    lf = [s for s in systems if any(r["metric"] == "lf_error" and r["system"] == s for r in rows)]
    lines = []
    for scene, composition in dict.fromkeys((r["scene"], r["config"]["composition"]) for r in rows):
        sel = [r for r in rows if r["scene"] == scene and r["config"]["composition"] == composition]
        lines += [
            f"### {scene}, composition: {composition}",
            "",
            "| k | "
            + " | ".join(f"fps ({s})" for s in systems)
            + " | "
            + " | ".join(f"SSIM ({s})" for s in systems)
            + "".join(f" | LF error ({s})" for s in lf)
            + " |",
            "|---" * (1 + 2 * len(systems) + len(lf)) + "|",
        ]
        for k in sorted({r["config"]["k"] for r in sel}):

            def get(system: str, metric: str) -> float:
                return next(
                    (r["value"] for r in sel if (r["system"], r["metric"], r["config"]["k"]) == (system, metric, k)),
                    float("nan"),
                )

            lines.append(
                f"| {k} | "
                + " | ".join(f"{get(s, 'fps'):.1f}" for s in systems)
                + " | "
                + " | ".join(f"{get(s, 'ssim'):.3f}" for s in systems)
                + "".join(f" | {get(s, 'lf_error'):.4f}" for s in lf)
                + " |"
            )
        lines.append("")
    return "\n".join(lines)


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Frame rate and SSIM against the GI-map period k, per scene, warp and composition; and the Table 3
    Markdown (``frequency_table.md``), both from the CSV."""
    from gicore.plotting import plt, save, ticker

    rows = read_rows(csv_path)
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for scene in scenes:
        for system in dict.fromkeys(r["system"] for r in rows):
            for composition, style in (("blend", "-o"), ("residual", "--s")):
                for ax, metric in zip(axes, ("fps", "ssim")):
                    sel = [
                        r
                        for r in rows
                        if (r["scene"], r["system"], r["metric"], r["config"]["composition"])
                        == (scene, system, metric, composition)
                    ]
                    if sel:
                        label = (
                            f"{system} ({composition})" if len(scenes) == 1 else f"{scene}: {system} ({composition})"
                        )
                        ax.plot(*zip(*sorted((r["config"]["k"], r["value"]) for r in sel)), style, ms=4, label=label)
    for ax, label in zip(axes, ("frames per second (GI cost amortised over k)", "mean SSIM vs path-traced GT")):
        ax.set_xlabel("GI-map period k [frames]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[0].yaxis.set_major_formatter(ticker.ScalarFormatter())
    axes[0].yaxis.set_minor_formatter(ticker.NullFormatter())
    axes[1].legend(fontsize=7)
    fig.suptitle("Inference frequency vs system performance (Table 3)")
    md = out_dir / "frequency_table.md"
    md.write_text(table(rows))
    return [save(fig, out_dir / "frequency.png"), md]


# -- bench report: the dashboard's section and the README's block ------------------------------------------
def dashboard_section(rows: Rows) -> list[Part]:
    """Table 3, then frame rate and SSIM against k per warp and composition."""
    need(rows, "fps", "ssim")
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    figures = []
    for metric, label, log in (("fps", "frames per second", True), ("ssim", "mean SSIM vs GT", False)):
        lines = []
        for key in dict.fromkeys((r["scene"], r["system"], r["config"]["composition"]) for r in pick(rows, metric)):
            name = f"{key[1]} ({key[2]})" if len(scenes) == 1 else f"{key[0]}: {key[1]} ({key[2]})"
            pts = [
                Point(r["config"]["k"], r["value"], f"{name}, k = {r['config']['k']}: {metric} {r['value']:.4g}")
                for r in pick(rows, metric)
                if (r["scene"], r["system"], r["config"]["composition"]) == key
            ]
            lines.append(Series(name, pts))
        figures.append(XYChart(lines, "GI-map period k [frames]", label, ylog=log))
    return [Table(table(rows)), Figure(tuple(figures))]


def readme_block(rows: Rows) -> list[Table]:
    """Table 3 under a line on where its GI maps come from."""
    need(rows, "fps", "ssim")
    c = rows[0]["config"]
    sources = ", ".join(str(s) for s in dict.fromkeys(r["config"].get("gi_source") for r in rows))
    head = (
        f"GI maps: {sources} (model: the generator's; gt: path-traced, a perfect-model stand-in); "
        f"{c.get('resolution')}², {c.get('frames')} frames; SSIM against path-traced GT at the local camera."
    )
    return [Table(head + "\n\n" + table(rows))]


BENCH = Bench(
    "frequency",
    FrequencyConfig,
    measure,
    plot,
    help="Table 3: GI-map period k against fps and SSIM, with and without warping, both compositions.",
    dashboard=Section("table3", "Table 3: inference frequency", 30, dashboard_section),
    readme=Block("Inference frequency, Table 3", 40, readme_block),
)
