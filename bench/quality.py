"""`bench quality` (paper Fig. 6): GI-map quality of GIGAN, Deep Shading, Deep Illumination and DI alone.

Every model is an exported ONNX generator run by onnxruntime exactly as the client runs it, on the held-out
validation frames of each scene's dataset, scored on tone-mapped images against path-traced GT: RMSE, SSIM,
PSNR, ``lf_error``, ``checker_error`` and ``shadow_tint`` (:mod:`gicore.metrics`); "di_only" scores the DI input
itself. Inference time is the median of repeated ``predict`` calls after warm-up. With ``--renderers
gl,mitsuba`` every model is scored on each renderer's inputs of the same frames, paired (``ssim_diff``,
``lf_error_ratio``), against :data:`GL_SSIM_LOSS_MAX` and :data:`GL_LF_RISE_MAX`. The grid
(``quality_grid.png``) shows inputs, maps, GT and error maps. docs/architecture.md, bench quality.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from bench.common import QUICK_DATASET
from bench.exported_models import model_info
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, need, pick
from bench.svg import BarChart
from gicore.dataset import INPUT_RENDERERS, DatasetMeta, frame_paths, load_frame, read_meta
from gicore.dataset_cli import FrameRenderer, build_dataset, render_inputs
from gicore.error_policy import UserError
from gicore.gl.lod import LOD_CHOICES
from gicore.loop import CLIENT_LOD
from gicore.metrics import CHECKER_PERIOD, LF_SIGMA, all_metrics, checker_error, lf_difference, shadow_tint
from gicore.results import Results, read_rows
from gicore.scene import SceneSpec, builtin_scenes, load_scene
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
#: The rule for the GL client's inputs: a model on gl inputs may lose at most this much SSIM against
#: mitsuba inputs on any scene, and raise the LF error by at most this fraction; beyond either, it is to be
#: fine-tuned on gl inputs.
GL_SSIM_LOSS_MAX = 0.005
GL_LF_RISE_MAX = 0.20
#: The renderer every other renderer's inputs are compared with (``ssim_diff``, ``lf_error_ratio``).
REFERENCE_RENDERER = "mitsuba"


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
    #: Renderers of the models' inputs (DI + G-buffers), scored side by side on the same frames and GT: each
    #: one's inputs as gicore-dataset --renderer stores them (the dataset's own, or rendered now).
    renderers: tuple[Literal[INPUT_RENDERERS], ...] = ("mitsuba",)  # type: ignore[valid-type]
    #: Level of detail of the gl inputs (gicore.gl.GLRenderer's lod; default the clients': auto, per view).
    gl_lod: Literal[LOD_CHOICES] = CLIENT_LOD  # type: ignore[valid-type]

    @classmethod
    def quick(cls) -> QualityConfig:
        return cls(datasets=None, max_frames=3, timing_repeats=5, grid_frames=1)

    def check(self) -> None:
        for name, path in self.models.items():
            model_info(path, f"--models {name}")
        unknown = [r for r in self.renderers if r not in INPUT_RENDERERS]
        if unknown or len(set(self.renderers)) != len(self.renderers):
            raise UserError(
                f"--renderers {','.join(self.renderers)} is not a list of distinct renderers",
                f"give some of {', '.join(INPUT_RENDERERS)}, each once",
            )
        if "gl" in self.renderers:
            from gicore.gl import gl_available

            ok, why = gl_available()
            if not ok:
                raise UserError(f"--renderers gl: {why}", "leave gl out of --renderers on this machine")


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


def input_renderers(cfg: QualityConfig, meta: DatasetMeta, root: Path) -> dict[str, FrameRenderer | None]:
    """Per renderer of ``cfg.renderers``: None where the dataset's stored inputs are that renderer's, else the
    :class:`FrameRenderer` that renders them now (UserError when the dataset's scene spec does not load)."""
    out: dict[str, FrameRenderer | None] = {}
    for renderer in cfg.renderers:
        if renderer == meta.renderer and (renderer == "mitsuba" or meta.lod == cfg.gl_lod):
            out[renderer] = None
            continue
        try:
            spec = SceneSpec.from_dict(meta.scene)
        except (OSError, ValueError) as err:
            raise UserError(
                f"{root} holds {meta.renderer} inputs and its scene spec does not load to render {renderer}'s"
                f" ({' '.join(str(err).split())})",
                f"leave {renderer} out of --renderers for it",
            ) from None
        out[renderer] = FrameRenderer(spec, meta.resolution, renderer, cfg.gl_lod)
    return out


def measure(cfg: QualityConfig, res: Results) -> None:
    from gigan_local.inference import GIModel

    models = {name: GIModel(path, threads=cfg.threads) for name, path in cfg.models.items()}
    infos = {name: model_info(path, f"--models {name}") for name, path in cfg.models.items()}
    systems = ["di_only", *models]
    several = len(cfg.renderers) > 1
    grid: list[list[GridCell]] = []
    for scene in cfg.scenes:
        root = dataset_root(cfg, res, scene)
        meta = read_meta(root)
        paths = frame_paths(root, "val")[: cfg.max_frames]
        records = meta.split_frames("val")[: cfg.max_frames]
        renderers = input_renderers(cfg, meta, root)
        scores: dict[tuple[str, str], list[dict[str, float]]] = {(n, r): [] for r in cfg.renderers for n in systems}
        levels: list[int] = []  # the levels of detail the gl inputs rendered now were drawn at
        for i, (record, path) in enumerate(zip(records, paths)):
            stored = load_frame(path, meta.buffers)
            reference = tonemap(stored["gt"])
            for renderer, frame_renderer in renderers.items():
                frame = stored
                if frame_renderer is not None:
                    frame = stored | render_inputs(frame_renderer, meta, record)
                    if renderer == "gl":
                        levels.append(frame_renderer.gl.last_level)
                outputs = {"di_only": frame["di"]} | {name: m.predict(frame) for name, m in models.items()}
                mapped = {name: tonemap(radiance) for name, radiance in outputs.items()}
                for name, image in mapped.items():
                    extra = {
                        "checker_error": checker_error(image, reference),
                        "shadow_tint": shadow_tint(image, reference, mapped["di_only"]),
                    }
                    scores[name, renderer].append(all_metrics(image, reference) | extra)
                if i < cfg.grid_frames:
                    grid += grid_rows(frame, mapped, reference, f"{scene} #{i}" + (f" {renderer}" if several else ""))
        for (name, renderer), per_frame in scores.items():
            config = infos.get(name, {}) | {"renderer": renderer}
            if renderer == "gl":
                config |= {"gl_lod": meta.lod if renderers[renderer] is None else cfg.gl_lod}
                config |= {"gl_level_mean": float(np.mean(levels))} if levels else {}
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
        add_comparisons(res, scene, scores, infos)
        for name, model in models.items():
            frame = load_frame(paths[0], meta.buffers)
            samples, _ = time_repeats(lambda: model.predict(frame), cfg.timing_repeats, warmup=3)
            res.add_timing(
                system=name, scene=scene, metric="inference_time", samples_s=samples, threads=cfg.threads, **infos[name]
            )
    if grid:
        save_grid(grid, ["DI", "albedo", "normal", *models, "GT"], res.output("quality_grid.png"), GRID_CAPTION)


def add_comparisons(
    res: Results, scene: str, scores: dict[tuple[str, str], list[dict[str, float]]], infos: dict[str, dict]
) -> None:
    """Per system, every renderer's inputs against :data:`REFERENCE_RENDERER`'s on the same frames: the paired
    SSIM difference (mean and standard error) and the ratio of the mean LF errors."""
    for (name, renderer), per_frame in scores.items():
        ref = scores.get((name, REFERENCE_RENDERER))
        if renderer == REFERENCE_RENDERER or ref is None:
            continue
        config = infos.get(name, {}) | {"renderer": renderer, "versus": REFERENCE_RENDERER, "frames": len(per_frame)}
        diff = np.array([a["ssim"] - b["ssim"] for a, b in zip(per_frame, ref)])
        se = float(diff.std(ddof=1) / math.sqrt(len(diff))) if len(diff) > 1 else math.nan
        lf_ref = float(np.mean([b["lf_error"] for b in ref]))
        lf_ratio = float(np.mean([a["lf_error"] for a in per_frame])) / lf_ref if lf_ref > 0 else math.nan
        res.add(system=name, scene=scene, metric="ssim_diff", value=float(diff.mean()), unit="1", stat="mean", **config)
        res.add(system=name, scene=scene, metric="ssim_diff", value=se, unit="1", stat="se", **config)
        res.add(system=name, scene=scene, metric="lf_error_ratio", value=lf_ratio, unit="x", stat="ratio", **config)


def renderer_of(row: dict) -> str:
    """The renderer of a row's inputs (CSVs older than ``--renderers`` scored mitsuba datasets only)."""
    return row["config"].get("renderer", REFERENCE_RENDERER)


def series(rows: Rows) -> dict[tuple[str, str], str]:
    """(system, renderer) of the mean rows, in order, with its label: the system, and its renderer when
    the rows hold more than one."""
    keys = list(
        dict.fromkeys((r["system"], renderer_of(r)) for r in rows if r["stat"] == "mean" and r["metric"] in UNITS)
    )
    several = len({k[1] for k in keys}) > 1
    return {k: f"{k[0]} ({k[1]})" if several else k[0] for k in keys}


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Fig. 6 style bars per scene and metric; and mean SSIM against inference time per model."""
    from gicore.plotting import plt, save, ticker

    rows = read_rows(csv_path)
    scenes = sorted({r["scene"] for r in rows})
    labels = series(rows)
    metrics = [m for m in UNITS if any(r["metric"] == m for r in rows)]  # CSVs older than lf_error lack it
    mean = {(r["scene"], r["system"], renderer_of(r), r["metric"]): r["value"] for r in rows if r["stat"] == "mean"}
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.7 * len(metrics), 4))
    width = 0.8 / len(labels)
    for ax, metric in zip(axes, metrics):
        for j, ((system, renderer), label) in enumerate(labels.items()):
            vals = [mean.get((s, system, renderer, metric), np.nan) for s in scenes]
            ax.bar(np.arange(len(scenes)) + j * width, vals, width, label=label)
        ax.set_xticks(np.arange(len(scenes)) + 0.4 - width / 2, scenes, rotation=25, ha="right", fontsize=7)
        ax.set_title(TITLES[metric], fontsize=9)
        if metric == "shadow_tint":
            ax.axhline(0.0, color="k", lw=0.6)
        ax.grid(axis="y", alpha=0.3)
    axes[-1].legend(fontsize=7)
    bars = save(fig, out_dir / "quality.png")

    fig, ax = plt.subplots(figsize=(10, 5))
    markers = {"fp32": "o", "fp16": "s", "int8": "^"}
    for (system, renderer), name in labels.items():
        times = [
            r["value"]
            for r in rows
            if r["system"] == system and r["metric"] == "inference_time" and r["stat"] == "median"
        ]
        ssims = [v for (_, sys_, rend, metric), v in mean.items() if (sys_, rend, metric) == (system, renderer, "ssim")]
        if times:
            cfg = next(r["config"] for r in rows if r["system"] == system and r["metric"] == "inference_time")
            x, y = float(np.median(times)), float(np.mean(ssims))
            label = f"{name} (ngf {cfg.get('ngf')}, {cfg.get('precision')}, {cfg.get('size_mib')} MiB)"
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
    """Fig. 6 as Markdown: per system (and renderer of its inputs, when there are several) and scene, the mean
    RMSE, SSIM, PSNR, LF and checkerboard errors, the shadow tint and the median inference time; then, when
    the rows compare renderers, :func:`renderer_table`."""
    need(rows, "ssim", "rmse", "psnr")
    scenes = list(dict.fromkeys(r["scene"] for r in pick(rows, "ssim")))
    lines = [
        "| system | scene | RMSE | SSIM | PSNR (dB) | LF error | checker error | shadow tint "
        "| inference ms (median) | config |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    mean = {(r["scene"], r["system"], renderer_of(r), r["metric"]): r for r in rows if r["stat"] == "mean"}
    median = {(r["scene"], r["system"], r["metric"]): r for r in rows if r["stat"] == "median"}
    for (system, renderer), label in series(rows).items():
        for scene in scenes:
            cells = [
                mean.get((scene, system, renderer, m))
                for m in ("rmse", "ssim", "psnr", "lf_error", "checker_error", "shadow_tint")
            ] + [median.get((scene, system, "inference_time"))]
            shown = ["—" if c is None else f"{c['value']:.4g}" for c in cells]
            config = next((c["config"] for c in cells if c is not None and c["config"]), {})
            knobs = ", ".join(f"{k}={v}" for k, v in config.items() if k not in ("frames", "renderer"))
            lines.append(f"| {label} | {scene} | " + " | ".join(shown) + f" | {knobs.replace('|', '/')} |")
    comparison = renderer_table(rows)
    return "\n".join(lines) + (f"\n\n{comparison}" if comparison else "")


def renderer_table(rows: Rows) -> str:
    """Each renderer's inputs against :data:`REFERENCE_RENDERER`'s, per system and scene (empty when the rows
    compare none): the paired SSIM difference ± its standard error, the LF error ratio, and whether the GL
    rule holds (SSIM lost at most :data:`GL_SSIM_LOSS_MAX`, LF error raised at most :data:`GL_LF_RISE_MAX`)."""
    diffs = pick(rows, "ssim_diff", "mean")
    if not diffs:
        return ""
    se = {(r["scene"], r["system"], renderer_of(r)): r["value"] for r in pick(rows, "ssim_diff", "se")}
    ratio = {(r["scene"], r["system"], renderer_of(r)): r["value"] for r in pick(rows, "lf_error_ratio")}
    lines = [
        f"| system | scene | inputs | SSIM − {REFERENCE_RENDERER}'s (± s.e.) | LF error / {REFERENCE_RENDERER}'s "
        f"| within the rule (SSIM ≥ −{GL_SSIM_LOSS_MAX:g}, LF ≤ {1 + GL_LF_RISE_MAX:g}×) |",
        "|---|---|---|---|---|---|",
    ]
    for r in diffs:
        key = (r["scene"], r["system"], renderer_of(r))
        lf = ratio.get(key, math.nan)
        ok = r["value"] >= -GL_SSIM_LOSS_MAX and lf <= 1 + GL_LF_RISE_MAX
        lines.append(
            f"| {r['system']} | {r['scene']} | {key[2]} | {r['value']:+.4f} (± {se.get(key, math.nan):.4f}) "
            f"| {lf:.3f}× | {'yes' if ok else '**no**'} |"
        )
    return "\n".join(lines)


def dashboard_section(rows: Rows) -> list[Part]:
    """A bar chart per error metric (scenes × systems and renderers), then the table."""
    need(rows, "ssim", "rmse", "psnr")
    scenes = list(dict.fromkeys(r["scene"] for r in pick(rows, "ssim")))
    labels = series(rows)
    figures = []
    # lf_error: the low-frequency error (gicore.metrics.lf_error); quality CSVs older than it have none ("—").
    shown_metrics = (
        ("rmse", "RMSE (tone-mapped)"),
        ("ssim", "SSIM"),
        ("psnr", "PSNR [dB]"),
        ("lf_error", "LF error (tone-mapped)"),
    )
    for metric, label in shown_metrics:
        value = {(r["scene"], r["system"], renderer_of(r)): r["value"] for r in pick(rows, metric, "mean")}
        if value:
            figures.append(
                BarChart(scenes, {name: [value.get((sc, *k)) for sc in scenes] for k, name in labels.items()}, label)
            )
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
