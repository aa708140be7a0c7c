"""`bench quality` (paper Fig. 6): GI-map quality of GIGAN, Deep Shading, Deep Illumination and DI alone.

Every model is an exported ONNX generator (``gigan-export``) run by onnxruntime exactly as the client
runs it, on the held-out validation frames of each scene's dataset. Metrics (RMSE/SSIM/PSNR, SPEC §3)
compare tone-mapped predictions with tone-mapped path-traced GT; "di_only" scores the DI input itself
(what a client without GI shows). Inference time is the median of repeated ``predict`` calls after
warm-up, so each model is also a point of error against run time (width and precision knobs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.models import model_info
from bench.runner import Bench
from gicore.cli import UserError
from gicore.dataset import frame_paths, load_frame, read_meta
from gicore.dataset_cli import DatasetConfig, build_dataset
from gicore.metrics import all_metrics
from gicore.results import Results, read_rows
from gicore.scene import builtin_scenes, load_scene
from gicore.timing import time_repeats
from gicore.tonemap import tonemap
from gigan_local.inference import DEFAULT_MODEL

UNITS = {"rmse": "1", "ssim": "1", "psnr": "dB"}
#: The small dataset a fresh checkout renders per scene (``bench quality --quick``, ``bench run-default``):
#: 6 training and 3 held-out frames at 256², the shipped model's resolution (about 7 s per scene on 2 cores).
QUICK_DATASET = DatasetConfig(n_train=6, n_val=3, resolution=256, spp=64, denoise=True)


@dataclass(frozen=True)
class QualityConfig:
    """Which models to score on which datasets."""

    #: Root of per-scene datasets (gicore-dataset --out); none: render QUICK_DATASET per scene into <out>/dataset.
    datasets: Path | None = Path("data/datasets")
    #: Scene names (dataset folders under --datasets).
    scenes: tuple[str, ...] = tuple(builtin_scenes())
    #: System name -> exported ONNX model (gigan-export), scored side by side.
    models: dict[str, Path] = field(default_factory=lambda: {"gigan": DEFAULT_MODEL})
    #: Score at most this many validation frames per scene; none: all.
    max_frames: int | None = None
    #: Timed inference calls per model and scene, after three warm-ups.
    timing_repeats: int = 20
    #: onnxruntime intra-op threads.
    threads: int = 2
    #: Frames per scene in the image grid (quality_grid.png); 0: no grid.
    grid_frames: int = field(default=2, metadata={"min": 0})

    @classmethod
    def quick(cls) -> QualityConfig:
        return cls(datasets=None, max_frames=3, timing_repeats=5, grid_frames=1)

    def check(self) -> None:
        for name, path in self.models.items():
            model_info(path, f"--models {name}")


def dataset_root(cfg: QualityConfig, res: Results, scene: str) -> Path:
    """The dataset folder of ``scene``: under ``--datasets``, or rendered now into ``<out>/dataset``."""
    if cfg.datasets is None:
        spec = load_scene(scene)
        root = res.out / "dataset" / spec.name
        build_dataset(spec, root, QUICK_DATASET, progress=False)
        return root
    root = cfg.datasets / scene
    render = f"render it with `gicore-dataset {scene} --out {cfg.datasets} --val 10 --resolution 256`, or use --quick"
    if not (root / "meta.json").is_file():
        raise UserError(f"--datasets {cfg.datasets}: no dataset of {scene} ({root / 'meta.json'} is missing)", render)
    if not frame_paths(root, "val"):
        raise UserError(f"--datasets {cfg.datasets}: {root} has no validation frames", render)
    return root


def measure(cfg: QualityConfig, res: Results) -> None:
    from gigan_local.inference import GIModel

    models = {name: GIModel(path, threads=cfg.threads) for name, path in cfg.models.items()}
    infos = {name: model_info(path, f"--models {name}") for name, path in cfg.models.items()}
    grid: list[list[np.ndarray]] = []
    for scene in cfg.scenes:
        root = dataset_root(cfg, res, scene)
        meta = read_meta(root)
        paths = frame_paths(root, "val")[: cfg.max_frames]
        scores: dict[str, list[dict[str, float]]] = {"di_only": []} | {name: [] for name in models}
        for i, path in enumerate(paths):
            frame = load_frame(path, meta.buffers)
            reference = tonemap(frame["gt"])
            outputs = {"di_only": frame["di"]} | {name: m.predict(frame) for name, m in models.items()}
            for name, radiance in outputs.items():
                scores[name].append(all_metrics(tonemap(radiance), reference))
            if i < cfg.grid_frames:
                grid.append(
                    [tonemap(frame["di"]), frame["albedo"], frame["normal"] * 0.5 + 0.5] + [tonemap(outputs[n]) for n in models] + [reference]
                )
        for name, per_frame in scores.items():
            config = infos.get(name, {})
            for metric in UNITS:
                values = [s[metric] for s in per_frame]
                res.add(
                    system=name,
                    scene=scene,
                    metric=metric,
                    value=float(np.mean(values)),
                    unit=UNITS[metric],
                    stat="mean",
                    frames=len(values),
                    **config,
                )
        for name, model in models.items():
            frame = load_frame(paths[0], meta.buffers)
            samples, _ = time_repeats(lambda: model.predict(frame), cfg.timing_repeats, warmup=3)
            res.add_timing(system=name, scene=scene, metric="inference_time", samples_s=samples, threads=cfg.threads, **infos[name])
    if grid:
        _save_grid(grid, ["DI", "albedo", "normal", *models, "GT"], res.output("quality_grid.png"))


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Fig. 6 style bars per scene and metric; and mean SSIM against inference time per model."""
    from gicore.plotting import plt, save, ticker

    rows = read_rows(csv_path)
    scenes = sorted({r["scene"] for r in rows})
    systems = list(dict.fromkeys(r["system"] for r in rows if r["stat"] == "mean"))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    width = 0.8 / len(systems)
    for ax, metric in zip(axes, UNITS):
        for j, system in enumerate(systems):
            vals = [
                next(
                    (r["value"] for r in rows if r["scene"] == s and r["system"] == system and r["metric"] == metric and r["stat"] == "mean"), np.nan
                )
                for s in scenes
            ]
            ax.bar(np.arange(len(scenes)) + j * width, vals, width, label=system)
        ax.set_xticks(np.arange(len(scenes)) + 0.4 - width / 2, scenes, rotation=25, ha="right", fontsize=7)
        ax.set_title(f"{metric.upper()} ({'lower' if metric == 'rmse' else 'higher'} is better)")
        ax.grid(axis="y", alpha=0.3)
    axes[2].legend(fontsize=7)
    bars = save(fig, out_dir / "quality.png")

    fig, ax = plt.subplots(figsize=(10, 5))
    markers = {"fp32": "o", "fp16": "s", "int8": "^"}
    for system in systems:
        times = [r["value"] for r in rows if r["system"] == system and r["metric"] == "inference_time" and r["stat"] == "median"]
        ssims = [r["value"] for r in rows if r["system"] == system and r["metric"] == "ssim"]
        if times:
            cfg = next(r["config"] for r in rows if r["system"] == system and r["metric"] == "inference_time")
            x, y = float(np.median(times)), float(np.mean(ssims))
            label = f"{system} (ngf {cfg.get('ngf')}, {cfg.get('precision')}, {cfg.get('size_mib')} MiB)"
            ax.scatter(x, y, s=45, marker=markers.get(cfg.get("precision"), "x"), label=label, alpha=0.8)
    ax.legend(fontsize=6, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(ticker.ScalarFormatter())
    ax.xaxis.set_minor_formatter(ticker.ScalarFormatter())
    ax.tick_params(axis="x", which="minor", labelsize=6)
    ax.set_xlabel("median onnxruntime inference time per frame [ms] (log)")
    ax.set_ylabel("mean SSIM over scenes")
    ax.grid(alpha=0.3, which="both")
    ax.set_title("GI-map error against run time")
    return [bars, save(fig, out_dir / "quality_pareto.png")]


def _save_grid(rows: list[list[np.ndarray]], labels: list[str], png: Path) -> None:
    from PIL import Image, ImageDraw

    sheet = np.concatenate([np.concatenate(r, axis=1) for r in rows], axis=0)
    header = 16
    img = Image.new("RGB", (sheet.shape[1], sheet.shape[0] + header), "white")
    img.paste(Image.fromarray((np.clip(sheet, 0, 1) * 255).astype(np.uint8)), (0, header))
    draw = ImageDraw.Draw(img)
    w = sheet.shape[1] // len(labels)
    for i, label in enumerate(labels):
        draw.text((i * w + 3, 2), label, fill="black")
    img.save(png)


BENCH = Bench(
    "quality", QualityConfig, measure, plot, help="Fig. 6: RMSE/SSIM/PSNR of each model and of DI alone on held-out frames, plus inference ms."
)
