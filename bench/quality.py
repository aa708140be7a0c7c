"""`bench quality` (paper Fig. 6): GI-map quality of GIGAN, Deep Shading, Deep Illumination and DI alone, each
an exported ONNX generator run as the client runs it on held-out frames; with ``--renderers gl,mitsuba`` each
renderer's inputs paired against :data:`GL_SSIM_LOSS_MAX` and :data:`GL_LF_RISE_MAX` (docs/architecture.md,
bench quality)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Literal

import numpy as np

from bench.quality_grid import GRID_CAPTION, grid_rows
from bench.runner import Bench, Block, Section
from gicore import option_groups
from gicore.dataset import INPUT_RENDERERS, frame_paths, load_frame, read_meta
from gicore.dataset_cli import inputs_renderer, render_inputs
from gicore.error_policy import UserError
from gicore.gl.lod import LOD_CHOICES
from gicore.metrics import CHECKER_PERIOD, LF_SIGMA, all_metrics, checker_error, shadow_tint
from gicore.present.declarations import Chart, Column, Figure, Image, Rows, Table, flat, matches, unique, wide
from gicore.present.sheet import Cell, save_sheet
from gicore.results import Results
from gicore.run_config import CLIENT_LOD
from gicore.scene import builtin_scenes
from gicore.timing import time_repeats
from gicore.tonemap import tonemap
from gigan_local.inference import DEFAULT_MODEL, model_info
from gigan_local.train_small import small_dataset

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
    scenes: tuple[str, ...] = option_groups.scenes(
        tuple(builtin_scenes()), note="their dataset folders under --datasets"
    )
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
    #: Score the held-out shapes and colours (gicore.heldout_cases, rendered into <datasets>/generalisation) instead
    #: of --scenes: object PSNR, its gain over DI alone and chroma error per case, each target met or MISSED.
    generalisation: bool = False

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
        return small_dataset(scene, res.out / "dataset")
    root = cfg.datasets / scene
    render = f"render it with `gicore-dataset {scene} --out {cfg.datasets} --val 10 --resolution 256`, or use --quick"
    if not (root / "meta.json").is_file():
        raise UserError(f"--datasets {cfg.datasets}: no dataset of {scene} ({root / 'meta.json'} is missing)", render)
    if not frame_paths(root, "val"):
        raise UserError(f"--datasets {cfg.datasets}: {root} has no validation frames", render)
    return root


def measure(cfg: QualityConfig, res: Results) -> None:
    from gigan_local.inference import GIModel

    if cfg.generalisation:
        return measure_generalisation(cfg, res)

    models = {name: GIModel(path, threads=cfg.threads) for name, path in cfg.models.items()}
    infos = {name: model_info(path, f"--models {name}") for name, path in cfg.models.items()}
    systems = ["di_only", *models]
    several = len(cfg.renderers) > 1
    grid: list[list[Cell]] = []
    for scene in cfg.scenes:
        root = dataset_root(cfg, res, scene)
        meta = read_meta(root)
        paths = frame_paths(root, "val")[: cfg.max_frames]
        records = meta.split_frames("val")[: cfg.max_frames]
        renderers = {r: inputs_renderer(meta, root, r, cfg.gl_lod, "--renderers") for r in cfg.renderers}
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
        save_sheet(grid, ["DI", "albedo", "normal", *models, "GT"], res.output("quality_grid.png"), GRID_CAPTION)


def measure_generalisation(cfg: QualityConfig, res: Results) -> None:
    from gigan_local.generalisation import UNITS as OBJECT_UNITS
    from gigan_local.generalisation import score_models

    root = (cfg.datasets or res.out / "dataset") / "generalisation"
    rows, checks = score_models(cfg.models, root, cfg.max_frames, cfg.threads)
    for r in rows:
        unit = (UNITS | OBJECT_UNITS)[r["metric"]]
        res.add(system=r["system"], scene=r["case"], metric=r["metric"], value=r["value"], unit=unit, stat="mean",
                frames=r["frames"])  # fmt: skip
    for c in checks:
        res.add(system=c["system"], scene=c["case"], metric="generalisation", value=int(c["met"]), unit="bool",
                stat="target_met", target=c["target"], measured=c["measured"])  # fmt: skip


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


# -- what it shows ------------------------------------------------------------------------------------------
def _labelled(rows: Rows, metric: str, stat: str = "mean") -> list[dict]:
    """The rows of ``metric`` and ``stat``, flat, each with its series' ``label``."""
    labels = series(rows)
    return [flat(r) | {"label": labels.get((r["system"], renderer_of(r)))} for r in rows if matches(r, metric, stat)]


def table_rows(rows: Rows) -> list[dict]:
    """Per series and scene: the mean of each error metric, the median inference time and the model's knobs."""
    scenes = unique(r["scene"] for r in rows if matches(r, "ssim"))
    mean = {(r["scene"], r["system"], renderer_of(r), r["metric"]): r for r in rows if r["stat"] == "mean"}
    median = {(r["scene"], r["system"], r["metric"]): r for r in rows if r["stat"] == "median"}
    out = []
    for (system, renderer), label in series(rows).items():
        for scene in scenes:
            found = {m: mean.get((scene, system, renderer, m)) for m in UNITS}
            found["inference"] = median.get((scene, system, "inference_time"))
            config = next((c["config"] for c in found.values() if c is not None and c["config"]), {})
            knobs = ", ".join(f"{k}={v}" for k, v in config.items() if k not in ("frames", "renderer"))
            values = {m: None if c is None else c["value"] for m, c in found.items()}
            out.append({"label": label, "scene": scene, "knobs": knobs, **values})
    return out


def renderer_rows(rows: Rows) -> list[dict]:
    """Each renderer's inputs against the reference renderer's, with the GL rule's verdict."""
    se = {(r["scene"], r["system"], renderer_of(r)): r["value"] for r in rows if matches(r, "ssim_diff", "se")}
    ratio = {(r["scene"], r["system"], renderer_of(r)): r["value"] for r in rows if matches(r, "lf_error_ratio")}
    out = []
    for r in (r for r in rows if matches(r, "ssim_diff", "mean")):
        key = (r["scene"], r["system"], renderer_of(r))
        lf = ratio.get(key, math.nan)
        ok = r["value"] >= -GL_SSIM_LOSS_MAX and lf <= 1 + GL_LF_RISE_MAX
        out.append(flat(r) | {"inputs": key[2], "se": se.get(key), "lf": lf, "ok": "yes" if ok else "**no**"})
    return out


def _pareto_points(rows: Rows) -> list[dict]:
    """Per series: the median inference time against the mean SSIM over the scenes."""
    out = []
    for (system, renderer), label in series(rows).items():
        times = [r["value"] for r in rows if r["system"] == system and matches(r, "inference_time", "median")]
        ssims = [r["value"] for r in _labelled(rows, "ssim") if (r["system"], renderer_of(r)) == (system, renderer)]
        if times and ssims:
            c = next(r["config"] for r in rows if r["system"] == system and r["metric"] == "inference_time")
            model = f"{label} (ngf {c.get('ngf')}, {c.get('precision')}, {c.get('size_mib')} MiB)"
            out.append({"model": model, "time": float(np.median(times)), "ssim": float(np.mean(ssims))})
    return out


TABLE = Table(
    table_rows,
    (
        Column("system", "{label}"),
        Column("scene", "{scene}"),
        Column("RMSE", "{rmse:.4g}"),
        Column("SSIM", "{ssim:.4g}"),
        Column("PSNR (dB)", "{psnr:.4g}"),
        Column("LF error", "{lf_error:.4g}"),
        Column("checker error", "{checker_error:.4g}"),
        Column("shadow tint", "{shadow_tint:.4g}"),
        Column("inference ms (median)", "{inference:.4g}"),
        Column("config", "{knobs}"),
    ),
)
RENDERERS = Table(
    renderer_rows,
    (
        Column("system", "{system}"),
        Column("scene", "{scene}"),
        Column("inputs", "{inputs}"),
        Column(f"SSIM − {REFERENCE_RENDERER}'s (± s.e.)", "{value:+.4f} (± {se:.4f})"),
        Column(f"LF error / {REFERENCE_RENDERER}'s", "{lf:.3f}×"),
        Column(f"within the rule (SSIM ≥ −{GL_SSIM_LOSS_MAX:g}, LF ≤ {1 + GL_LF_RISE_MAX:g}×)", "{ok}"),
    ),
)
PARTS = (
    Figure(
        "quality",
        tuple(
            Chart(partial(_labelled, metric=m), "scene", series="{label}", kind="bar", title=title)
            for m, title in TITLES.items()
        ),
    ),
    Figure(
        "quality_pareto",
        (
            Chart(
                _pareto_points,
                "time",
                "ssim",
                series="{model}",
                kind="scatter",
                xlog=True,
                xlabel="median onnxruntime inference time per frame [ms]",
                ylabel="mean SSIM over scenes",
                title="GI-map error against run time",
            ),
        ),
    ),
    Image("quality_grid.png", where="readme"),  # the grid: thousands of pixels tall, a file to open
    TABLE,
    RENDERERS,
    Table(
        lambda rows: wide(
            rows, ("system", "scene"), {m: f"{m}/mean" for m in ("object_psnr", "gain_db", "chroma_error")}
        ),
        (
            Column("system", "{system}"),
            Column("case", "{scene}"),
            Column("object PSNR (dB)", "{object_psnr:.1f}"),
            Column("gain over DI alone (dB)", "{gain_db:+.1f}"),
            Column("chroma error", "{chroma_error:.3f}"),
        ),
        caption="Held-out shapes and colours (gicore.heldout_cases), on the object's own pixels, tone-mapped.",
    ),
    Table(
        lambda rows: [flat(r) | {"met": "met" if r["value"] else "MISSED"} for r in rows if r["stat"] == "target_met"],
        (
            Column("system", "{system}"),
            Column("case", "{scene}"),
            Column("target", "{target}"),
            Column("measured", "{measured:.3f}"),
            Column("met", "{met}"),
        ),
        notes=lambda rows: f"{sum(m := [r['value'] for r in rows if r['stat'] == 'target_met']):.0f} of {len(m)} met.",
    ),
)


BENCH = Bench(
    "quality",
    QualityConfig,
    measure,
    help="Fig. 6: RMSE/SSIM/PSNR and low-frequency error of each model and of DI alone on held-out frames, plus "
    "inference ms and error maps.",
    dashboard=Section("fig6", "Fig. 6: GI-map quality", 40),
    readme=Block("GI-map quality, Fig. 6", 50),
    parts=PARTS,
    needs=("ssim", "rmse", "psnr"),
)
