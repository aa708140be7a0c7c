"""`bench quality` (paper Fig. 6): GI-map quality of GIGAN, Deep Shading, Deep Illumination and DI alone.

Every model is an exported ONNX generator (``gigan-export``) run by onnxruntime exactly as the client
runs it, on the held-out validation frames of each scene's dataset. Metrics compare tone-mapped
predictions with tone-mapped path-traced GT: RMSE/SSIM/PSNR (SPEC §3); the low-frequency error
``lf_error`` (:func:`gicore.metrics.lf_error`), which sees the brightness blotches SSIM barely moves
under; the checkerboard error ``checker_error`` (:func:`gicore.metrics.checker_error`), the part of the
error that repeats on a 4x4 pixel tile; and ``shadow_tint`` (:func:`gicore.metrics.shadow_tint`), the
signed red tint where only indirect light arrives. "di_only" scores the DI input itself (what a
client without GI shows). Inference time is the median of repeated ``predict`` calls after warm-up, so
each model is also a point of error against run time (width and precision knobs).

The image grid (``quality_grid.png``) shows, per frame, the inputs, each model's map and the GT, and under
DI and under each model two error maps (:func:`grid_rows`): the per-channel |tone-mapped prediction − GT|
and the low-frequency signed error on a fixed diverging scale, so a blotch or a tint is seen at a glance.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.models import model_info
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, need, pick
from bench.svg import BarChart
from gicore.cli import UserError
from gicore.dataset import frame_paths, load_frame, read_meta
from gicore.dataset_cli import DatasetConfig, build_dataset
from gicore.metrics import CHECKER_PERIOD, LF_SIGMA, all_metrics, checker_error, lf_difference, shadow_tint
from gicore.results import Results, read_rows
from gicore.scene import builtin_scenes, load_scene
from gicore.timing import time_repeats
from gicore.tonemap import tonemap
from gigan_local.inference import DEFAULT_MODEL

UNITS = {"rmse": "1", "ssim": "1", "psnr": "dB", "lf_error": "1", "checker_error": "1", "shadow_tint": "1"}
#: Titles of the bar plots: what each metric is and which way is better.
TITLES = {
    "rmse": "RMSE (lower is better)",
    "ssim": "SSIM (higher is better)",
    "psnr": "PSNR (higher is better)",
    "lf_error": f"LF error (σ = {LF_SIGMA:g} px; lower is better)",
    "checker_error": f"checkerboard error ({CHECKER_PERIOD} px tile; lower is better)",
    "shadow_tint": "red tint in indirect-only light (0 is best)",
}
#: The grid's |error| images show |tone-mapped prediction − GT| times this gain (white from 1 / gain = 0.25 up).
GRID_ABS_GAIN = 4.0
#: The grid's low-frequency images map the blurred signed error (prediction − GT, channel mean) from
#: −GRID_LF_RANGE (blue: darker than GT) through 0 (white) to +GRID_LF_RANGE (red: brighter), clipped.
GRID_LF_RANGE = 0.1
GRID_LF_CMAP = "RdBu_r"
#: One grid cell: an HxWx3 image in [0, 1] and the text drawn on it ("" for none).
GridCell = tuple[np.ndarray, str]
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
    grid: list[list[GridCell]] = []
    for scene in cfg.scenes:
        root = dataset_root(cfg, res, scene)
        meta = read_meta(root)
        paths = frame_paths(root, "val")[: cfg.max_frames]
        scores: dict[str, list[dict[str, float]]] = {"di_only": []} | {name: [] for name in models}
        for i, path in enumerate(paths):
            frame = load_frame(path, meta.buffers)
            reference = tonemap(frame["gt"])
            outputs = {"di_only": frame["di"]} | {name: m.predict(frame) for name, m in models.items()}
            mapped = {name: tonemap(radiance) for name, radiance in outputs.items()}
            for name, image in mapped.items():
                extra = {
                    "checker_error": checker_error(image, reference),
                    "shadow_tint": shadow_tint(image, reference, mapped["di_only"]),
                }
                scores[name].append(all_metrics(image, reference) | extra)
            if i < cfg.grid_frames:
                grid += grid_rows(frame, mapped, reference, f"{scene} #{i}")
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
            res.add_timing(
                system=name, scene=scene, metric="inference_time", samples_s=samples, threads=cfg.threads, **infos[name]
            )
    if grid:
        save_grid(grid, ["DI", "albedo", "normal", *models, "GT"], res.output("quality_grid.png"), GRID_CAPTION)


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Fig. 6 style bars per scene and metric; and mean SSIM against inference time per model."""
    from gicore.plotting import plt, save, ticker

    rows = read_rows(csv_path)
    scenes = sorted({r["scene"] for r in rows})
    systems = list(dict.fromkeys(r["system"] for r in rows if r["stat"] == "mean"))
    metrics = [m for m in UNITS if any(r["metric"] == m for r in rows)]  # CSVs older than lf_error lack it
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.7 * len(metrics), 4))
    width = 0.8 / len(systems)
    for ax, metric in zip(axes, metrics):
        for j, system in enumerate(systems):
            vals = [
                next(
                    (
                        r["value"]
                        for r in rows
                        if r["scene"] == s and r["system"] == system and r["metric"] == metric and r["stat"] == "mean"
                    ),
                    np.nan,
                )
                for s in scenes
            ]
            ax.bar(np.arange(len(scenes)) + j * width, vals, width, label=system)
        ax.set_xticks(np.arange(len(scenes)) + 0.4 - width / 2, scenes, rotation=25, ha="right", fontsize=7)
        ax.set_title(TITLES[metric], fontsize=9)
        if metric == "shadow_tint":
            ax.axhline(0.0, color="k", lw=0.6)
        ax.grid(axis="y", alpha=0.3)
    axes[-1].legend(fontsize=7)
    bars = save(fig, out_dir / "quality.png")

    fig, ax = plt.subplots(figsize=(10, 5))
    markers = {"fp32": "o", "fp16": "s", "int8": "^"}
    for system in systems:
        times = [
            r["value"]
            for r in rows
            if r["system"] == system and r["metric"] == "inference_time" and r["stat"] == "median"
        ]
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


GRID_CAPTION = (  # ASCII: PIL's default font has no glyphs for sigma or the minus sign
    f"Per frame: row 1 inputs, maps, GT; row 2 |tone-mapped prediction - GT| x{GRID_ABS_GAIN:g} per channel (black 0, "
    f"full colour from {1 / GRID_ABS_GAIN:g}); row 3 Gaussian (sigma {LF_SIGMA:g} px) of the signed tone-mapped "
    "difference, "
    f"channel mean: blue -{GRID_LF_RANGE:g} (darker than GT), white 0, red +{GRID_LF_RANGE:g} (brighter), clipped. "
    "Under DI: DI alone's error. 'LF': that frame's lf_error."
)


def abs_error_image(prediction: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """|prediction - reference| per channel (both tone-mapped), times :data:`GRID_ABS_GAIN`, clipped to [0, 1]."""
    return np.clip(np.abs(prediction - reference) * GRID_ABS_GAIN, 0.0, 1.0)


def lf_colours(signed: np.ndarray) -> np.ndarray:
    """Signed values (any shape) as colours (shape + (3,)) of :data:`GRID_LF_CMAP` on ±:data:`GRID_LF_RANGE`,
    clipped."""
    from matplotlib import colormaps

    t = np.clip(0.5 + 0.5 * np.asarray(signed) / GRID_LF_RANGE, 0.0, 1.0)
    return np.asarray(colormaps[GRID_LF_CMAP](t))[..., :3]


def _legend(shape: tuple[int, ...], ramp: np.ndarray) -> np.ndarray:
    """A white cell with a horizontal colour ``ramp`` (Wx3) across its middle (its scale is written on it)."""
    h = shape[0]
    cell = np.ones(shape[:2] + (3,))
    cell[h // 3 : h * 2 // 3] = ramp[None]
    return cell


def grid_rows(
    frame: dict[str, np.ndarray], maps: dict[str, np.ndarray], reference: np.ndarray, title: str
) -> list[list[GridCell]]:
    """The three grid rows of one frame: ``[DI, albedo, normal, models..., GT]``; then under DI and under each
    model its |error| image (:func:`abs_error_image`); then its low-frequency signed error (:func:`lf_colours`
    of :func:`gicore.metrics.lf_difference`'s channel mean) with the frame's lf_error written on it. Legends
    stand under albedo. ``maps``: tone-mapped, ``"di_only"`` (the DI input) and the models in column order;
    ``reference``: the tone-mapped GT."""
    blank: GridCell = (np.ones_like(reference), "")
    models = [n for n in maps if n != "di_only"]
    signed = {n: lf_difference(maps[n], reference) for n in maps}
    abs_cells = {n: (abs_error_image(maps[n], reference), "|error|") for n in maps}
    lf_cells = {n: (lf_colours(d.mean(axis=-1)), f"LF {float(np.mean(np.abs(d))):.4f}") for n, d in signed.items()}
    x = np.linspace(0.0, 1.0, reference.shape[1])
    abs_legend = (
        _legend(reference.shape, np.repeat(x[:, None], 3, axis=1)),
        f"|error| x{GRID_ABS_GAIN:g}: 0 .. {1 / GRID_ABS_GAIN:g}+",
    )
    lf_legend = (
        _legend(reference.shape, lf_colours((2 * x - 1) * GRID_LF_RANGE)),
        f"LF signed: -{GRID_LF_RANGE:g} .. +{GRID_LF_RANGE:g}",
    )
    images = [(maps["di_only"], title), (frame["albedo"], ""), (frame["normal"] * 0.5 + 0.5, "")]
    return [
        images + [(maps[n], "") for n in models] + [(reference, "")],
        [abs_cells["di_only"], abs_legend, blank] + [abs_cells[n] for n in models] + [blank],
        [lf_cells["di_only"], lf_legend, blank] + [lf_cells[n] for n in models] + [blank],
    ]


def save_grid(rows: list[list[GridCell]], labels: list[str], png: Path, caption: str = "") -> Path:
    """Write the cells as one PNG: a header of column ``labels``, each cell's text on it, ``caption`` below."""
    from PIL import Image, ImageDraw

    sheet = np.concatenate([np.concatenate([img for img, _ in r], axis=1) for r in rows], axis=0)
    header = 16
    w = sheet.shape[1] // len(labels)
    h = sheet.shape[0] // len(rows)
    draw_probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    caption_lines = _wrap(caption, lambda t: draw_probe.textlength(t), sheet.shape[1] - 6) if caption else []
    footer = 14 * len(caption_lines) + (4 if caption_lines else 0)
    img = Image.new("RGB", (sheet.shape[1], sheet.shape[0] + header + footer), "white")
    img.paste(Image.fromarray((np.clip(sheet, 0, 1) * 255).astype(np.uint8)), (0, header))
    draw = ImageDraw.Draw(img)
    for i, label in enumerate(labels):
        draw.text((i * w + 3, 2), label, fill="black")
    for r, row in enumerate(rows):
        for c, (_, text) in enumerate(row):
            if text:
                x, y = c * w + 3, header + r * h + 3
                draw.rectangle(draw.textbbox((x, y), text), fill="white")
                draw.text((x, y), text, fill="black")
    for k, line in enumerate(caption_lines):
        draw.text((3, header + sheet.shape[0] + 2 + 14 * k), line, fill="black")
    png.parent.mkdir(parents=True, exist_ok=True)  # with --datasets nothing else has made --out yet
    img.save(png)
    return png


def _wrap(text: str, width_of, max_width: float) -> list[str]:
    lines, line = [], ""
    for word in text.split():
        candidate = f"{line} {word}".strip()
        if line and width_of(candidate) > max_width:
            lines.append(line)
            candidate = word
        line = candidate
    return [*lines, line] if line else lines


# -- bench report: the dashboard's section and the README's block ------------------------------------------
def table(rows: Rows) -> str:
    """Fig. 6 as Markdown: per system and scene, the mean RMSE, SSIM, PSNR, LF and checkerboard errors,
    the shadow tint and the median inference time."""
    need(rows, "ssim", "rmse", "psnr")
    scenes = list(dict.fromkeys(r["scene"] for r in pick(rows, "ssim")))
    systems = list(dict.fromkeys(r["system"] for r in pick(rows, "ssim")))
    lines = [
        "| system | scene | RMSE | SSIM | PSNR (dB) | LF error | checker error | shadow tint "
        "| inference ms (median) | config |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    mean = {(r["scene"], r["system"], r["metric"]): r for r in rows if r["stat"] in ("mean", "median")}
    for system in systems:
        for scene in scenes:
            cells = [
                mean.get((scene, system, m))
                for m in ("rmse", "ssim", "psnr", "lf_error", "checker_error", "shadow_tint", "inference_time")
            ]
            shown = ["—" if c is None else f"{c['value']:.4g}" for c in cells]
            config = next((c["config"] for c in cells if c is not None and c["config"]), {})
            knobs = ", ".join(f"{k}={v}" for k, v in config.items() if k not in ("frames",))
            lines.append(f"| {system} | {scene} | " + " | ".join(shown) + f" | {knobs.replace('|', '/')} |")
    return "\n".join(lines)


def dashboard_section(rows: Rows) -> list[Part]:
    """A bar chart per error metric (scenes × systems), then the table."""
    need(rows, "ssim", "rmse", "psnr")
    scenes = list(dict.fromkeys(r["scene"] for r in pick(rows, "ssim")))
    systems = list(dict.fromkeys(r["system"] for r in pick(rows, "ssim")))
    figures = []
    # lf_error: the low-frequency error (gicore.metrics.lf_error); quality CSVs older than it have none ("—").
    shown_metrics = (
        ("rmse", "RMSE (tone-mapped)"),
        ("ssim", "SSIM"),
        ("psnr", "PSNR [dB]"),
        ("lf_error", "LF error (tone-mapped)"),
    )
    for metric, label in shown_metrics:
        value = {(r["scene"], r["system"]): r["value"] for r in pick(rows, metric, "mean")}
        if value:
            figures.append(BarChart(scenes, {s: [value.get((sc, s)) for sc in scenes] for s in systems}, label))
    return [Figure(tuple(figures)), Table(table(rows))]


def readme_block(rows: Rows) -> list[Table]:
    """The same table as the dashboard's."""
    return [Table(table(rows))]


BENCH = Bench(
    "quality",
    QualityConfig,
    measure,
    plot,
    help="Fig. 6: RMSE/SSIM/PSNR and low-frequency error of each model and of DI alone on held-out frames, plus "
    "inference ms and error maps.",
    dashboard=Section("fig6", "Fig. 6: GI-map quality", 40, dashboard_section),
    readme=Block("GI-map quality, Fig. 6", 50, readme_block),
)
