"""`bench model-card`: a model card (Markdown) for an exported model, from files the project produced.

Every number comes from the training run (``config.json``, ``metrics.csv``), the export (``model.json``,
file sizes) and a ``bench quality`` CSV; nothing is typed by hand. ``MODEL_CARD.md`` is written into the
export folder (it travels with the model); the card's numbers also go to the tidy CSV, and the plot
compares the model's per-scene SSIM with DI alone.

On a fresh checkout (``--quick`` without ``--run``) the whole chain runs here, small: a GIGAN trained for
``--train-steps`` on the small dataset of ``--scenes`` (``bench training``'s runs), exported into
``<out>/export/<run>``, scored by ``bench quality`` on the same datasets into ``<out>/quality``.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from bench.common import train_small, training_minutes
from bench.runner import Bench, execute
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.metrics import LF_SIGMA
from gicore.present.declarations import Chart, Figure, flat, matches
from gicore.results import Results, read_rows

#: Where the logged step times were measured, by the run's last ``--device``.
STEP_WHERE = {"cpu": "on this machine's CPU", "cuda": "on the CUDA GPU it trained on (not this machine)"}
#: How the card names each U-Net up-sampling (``NetworkConfig.upsample``; exports older than it are transposed).
UPSAMPLING_WORDS = {
    "transposed": "4x4 stride-2 transposed-conv up-sampling",
    "resize": "nearest 2x resize + 3x3 conv up-sampling",
}


@dataclass(frozen=True)
class ModelCardConfig:
    """The model's run, export and quality results, or the small model to make first."""

    #: gigan-train run folder of the model; none: train a small one here (needs --train-steps; --quick sets it).
    run: Path | None = None
    #: gigan-export folder of the model (MODEL_CARD.md is written there); none: export the run into
    #: <out>/export/<run name>.
    export: Path | None = None
    #: A bench quality CSV that scored the exported model; none: score it here (bench quality on the small datasets).
    quality_csv: Path | None = None
    #: The model's system name in the quality CSV.
    system: str = "gigan"
    #: The command that rendered the training data (quoted in the card).
    dataset_command: str = "(not given)"
    #: The command that trained the model (quoted in the card).
    train_command: str = "(not given)"
    #: Steps of the small GIGAN trained here when --run is not given.
    train_steps: int | None = None
    #: Generator width (ngf) of the small GIGAN trained here.
    width: int = 8
    scenes: tuple[str, ...] = option_groups.scenes(
        note="the model trained here learns from their small datasets and is scored on them"
    )

    @classmethod
    def quick(cls) -> ModelCardConfig:
        return cls(train_steps=60)

    def check(self) -> None:
        if self.run is None and self.train_steps is None:
            raise UserError(
                "--run is not given: no model to describe",
                "give --run, --export and --quality-csv, or --quick to make a small model here",
            )
        if self.run is None and (self.export is not None or self.quality_csv is not None):
            raise UserError(
                "--export/--quality-csv given without --run", "give the run folder the exported model came from"
            )
        if self.run is not None and self.quality_csv is None:
            raise UserError(
                "--run given without --quality-csv",
                "score the exported model with `bench quality --models NAME=FILE` and pass its CSV",
            )
        required = {"--run": (self.run, ("config.json", "metrics.csv")), "--export": (self.export, ("model.json",))}
        for option, (folder, names) in required.items():
            for name in names if folder is not None else ():
                if not (folder / name).is_file():
                    raise UserError(
                        f"{option} {folder}: {folder / name} is missing", f"give the {option[2:]} folder of the model"
                    )
        if self.quality_csv is not None and not self.quality_csv.is_file():
            raise UserError(f"--quality-csv {self.quality_csv} is missing", "give a CSV written by bench quality")


def measure(cfg: ModelCardConfig, res: Results, quality: Bench) -> None:
    run, export, quality_csv = cfg.run, cfg.export, cfg.quality_csv
    dataset_command, train_command = cfg.dataset_command, cfg.train_command
    if run is None:  # the small chain; check() made sure train_steps is set
        [run] = train_small(cfg.scenes, (cfg.width,), cfg.train_steps, res)
        dataset_command = (
            f"bench model-card --quick: bench.common.QUICK_DATASET of {', '.join(cfg.scenes)} "
            f"into {res.out / 'dataset'}"
        )
        train_command = (
            f"bench model-card --quick: bench.common.train_small, GIGAN ngf {cfg.width}, {cfg.train_steps} steps"
        )
    if export is None:
        from gigan_local.export import export_onnx

        export = res.out / "export" / run.name
        export_onnx(run, export)
    if quality_csv is None:  # only in the small chain (check()): score on the small datasets it trained on
        model = export / json.loads((export / "model.json").read_text())["files"]["fp32"]
        scoring = dataclasses.replace(
            quality.config.quick(), scenes=cfg.scenes, models={cfg.system: model}, datasets=res.out / "dataset"
        )
        scored = execute(quality, scoring, res.out / "quality", res.seed)
        res.files += scored
        quality_csv = scored[0]
    res.files.append(write_model_card(run, export, quality_csv, cfg.system, dataset_command, train_command, res))


@dataclass(frozen=True)
class _Training:
    """What a gigan-train run folder says about the model: its train config and metrics rows, the last step,
    the logged step times (s) and their sum (min), and the validation metrics at the last step."""

    train: dict
    metrics: list[dict[str, str]]
    last_step: int
    step_s: list[float]
    compute_min: float
    val: dict[str, float]

    @classmethod
    def read(cls, run_dir: Path) -> _Training:
        train = json.loads((run_dir / "config.json").read_text())["train"]
        with (run_dir / "metrics.csv").open(newline="") as fh:
            metrics = list(csv.DictReader(fh))
        last_step = max(int(r["step"]) for r in metrics)
        step_rows = sorted((int(r["step"]), float(r["value"])) for r in metrics if r["metric"] == "step_seconds")
        compute_min = training_minutes(step_rows, [last_step])[0] if step_rows else float("nan")
        val = {r["metric"]: float(r["value"]) for r in metrics if r["split"] == "val" and int(r["step"]) == last_step}
        return cls(train, metrics, last_step, [v for _, v in step_rows], compute_min, val)


def write_model_card(
    run_dir: Path,
    export_dir: Path,
    quality_csv: Path,
    system: str,
    dataset_command: str,
    train_command: str,
    res: Results,
) -> Path:
    """Write ``export_dir/MODEL_CARD.md`` and add its numbers to ``res``; returns the card's path."""
    training = _Training.read(run_dir)
    model_doc = json.loads((export_dir / "model.json").read_text())
    rows = _quality_rows(quality_csv, system)
    sizes = {k: (export_dir / v).stat().st_size / 2**20 for k, v in model_doc["files"].items()}
    _record(res, export_dir.name, run_dir, training, rows, system, quality_csv, sizes)
    lines = [
        *_model_lines(export_dir.name, model_doc, training, dataset_command, train_command),
        *_scene_lines(rows, system),
        *_file_lines(model_doc, sizes, quality_csv, rows),
    ]
    card = export_dir / "MODEL_CARD.md"
    card.write_text("\n".join(lines) + "\n")
    return card


def _quality_rows(quality_csv: Path, system: str) -> list[dict]:
    """The rows of a bench quality CSV that scored ``system`` on one renderer's inputs."""
    rows = read_rows(quality_csv)
    if not any(r["system"] == system for r in rows):
        raise UserError(
            f"--quality-csv {quality_csv} has no rows of system {system!r}",
            "pass --system with the model's name in that CSV",
        )
    # a card states one set of numbers: a CSV scored on several renderers' inputs would mix them per cell
    renderers = sorted({r["config"].get("renderer", "mitsuba") for r in rows if r["system"] == system})
    if len(renderers) > 1:
        raise UserError(
            f"--quality-csv {quality_csv} scores {system!r} on the inputs of renderers {', '.join(renderers)}",
            "score the model with one `bench quality --renderers R` for its card",
        )
    return rows


def _record(
    res: Results, model_name: str, run_dir: Path, training: _Training, rows: list[dict], system: str,
    quality_csv: Path, sizes: dict[str, float],
) -> None:  # fmt: skip
    """The card's numbers as tidy rows: training, validation, the quality CSV's means (and median inference
    time) of the model and of DI alone, the file sizes."""
    res.add(system=model_name, scene="all", metric="training_steps", value=training.last_step, unit="count",
            run=run_dir.name)  # fmt: skip
    res.add(system=model_name, scene="all", metric="training_time", value=training.compute_min, unit="min",
            stat="sum", run=run_dir.name)  # fmt: skip
    for metric, value in training.val.items():
        unit = "dB" if metric == "psnr" else "1"
        res.add(system=model_name, scene="all", metric=f"val_{metric}", value=value, unit=unit,
                step=training.last_step)  # fmt: skip
    for r in rows:
        if r["system"] in (system, "di_only") and (
            r["stat"] == "mean" or r["metric"] == "inference_time" and r["stat"] == "median"
        ):
            res.add(system=model_name if r["system"] == system else "di_only", scene=r["scene"], metric=r["metric"],
                    value=r["value"], unit=r["unit"], stat=r["stat"], source=str(quality_csv),
                    source_run=r["run_id"])  # fmt: skip
    for precision, mib in sizes.items():
        res.add(system=model_name, scene="all", metric="file_size", value=mib, unit="MiB", precision=precision)


def _model_lines(
    name: str, model_doc: dict, training: _Training, dataset_command: str, train_command: str
) -> list[str]:
    """The card's title, the generator, its data and its training."""
    train, val, step_s = training.train, training.val, training.step_s
    return [
        f"# Model card: {name}",
        "",
        f"Generator `{model_doc['model']}` (U-Net, ngf {model_doc['ngf']}, {model_doc['n_down']} down-samplings, "
        f"{UPSAMPLING_WORDS[model_doc.get('network', {}).get('upsample', 'transposed')]}), "
        f"inputs {model_doc['input']['buffers']} ({model_doc['in_channels']} channels) at {model_doc['resolution']}², "
        "output: the path-traced GI image, tone-mapped to [-1, 1] (`gicore.tonemap`). "
        f"One model for the {len(train['datasets'])} scene(s) of its training data.",
        "",
        "## Data",
        f"`{dataset_command}`",
        "",
        f"Datasets: {', '.join(Path(d).name for d in train['datasets'])} "
        "(train splits train, held-out val splits validate: "
        "validation frames come from a different camera trajectory).",
        "",
        "## Training",
        f"`{train_command}`",
        "",
        f"Loss: {train['model']} (λ_L1 {train['lambda_L1']}, λ_GP {train['lambda_gp']}, n_critic {train['n_critic']}), "
        f"Adam lr {train['lr']} β=({train['beta1']}, {train['beta2']}), batch {train['batch_size']}, "
        + (f"warm-started from `{train['init_generator']}`, " if train.get("init_generator") else "")
        + (f"random {train['crop']}² crops" if train["crop"] else "whole frames")
        + f", seed {train['seed']}. "
        f"Stopped at optimizer step {training.last_step} (epoch {max(int(r['epoch']) for r in training.metrics)}); "
        f"median step time {sorted(step_s)[len(step_s) // 2]:.3g} s {STEP_WHERE[train.get('device', 'cpu')]}, "
        f"{training.compute_min:.3g} min of steps in all "
        "(validation and checkpoints not counted; logged per epoch in metrics.csv). "
        f"Validation at the last step ({train['max_val_frames'] or 'all'} evenly spaced val frames of the training "
        "data sets): "
        f"SSIM {val.get('ssim', float('nan')):.4f}, "
        f"PSNR {val.get('psnr', float('nan')):.2f} dB, RMSE {val.get('rmse', float('nan')):.4f}"
        + (f", LF error {val['lf_error']:.4f}." if "lf_error" in val else "."),
        "",
    ]


def _scene_lines(rows: list[dict], system: str) -> list[str]:
    """The card's table of the quality CSV's metrics per scene, the model's beside DI alone's."""

    def cell(sys: str, scene: str, metric: str, stat: str = "mean") -> str:
        v = [
            r["value"]
            for r in rows
            if r["system"] == sys and r["scene"] == scene and r["metric"] == metric and r["stat"] == stat
        ]
        digits = {"psnr": 2, "inference_time": 1}.get(metric, 4)
        return f"{v[0]:.{digits}f}" if v else "n/a"

    scenes = sorted({r["scene"] for r in rows})
    lf_missing = any(cell(s, scene, "lf_error") == "n/a" for s in (system, "di_only") for scene in scenes)
    lines = [
        "## Metrics per scene (`bench quality`, all held-out frames, tone-mapped)",
        "",
        f"LF error: low-frequency error, mean |Gaussian(σ = {LF_SIGMA:g} px) of the tone-mapped difference| "
        "(`gicore.metrics.lf_error`; lower is better): the brightness blotches SSIM barely sees"
        + (". n/a: the quality CSV predates it." if lf_missing else "."),
        "",
        "| scene | SSIM | PSNR dB | RMSE | LF error | DI alone SSIM | DI alone LF error | median inference ms |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scene in scenes:
        lines.append(
            f"| {scene} | {cell(system, scene, 'ssim')} | {cell(system, scene, 'psnr')} | "
            f"{cell(system, scene, 'rmse')} | {cell(system, scene, 'lf_error')} | {cell('di_only', scene, 'ssim')} | "
            f"{cell('di_only', scene, 'lf_error')} | "
            f"{cell(system, scene, 'inference_time', 'median')} |"
        )
    return lines


def _file_lines(model_doc: dict, sizes: dict[str, float], quality_csv: Path, rows: list[dict]) -> list[str]:
    """The card's list of the exported files, and where its metrics came from."""
    return [
        "",
        "## Files",
        *[
            f"- `{model_doc['files'][k]}`: {k} weights, {sizes[k]:.2f} MiB, "
            f"max |onnxruntime − torch| = {model_doc['max_abs_diff_vs_torch'][k]:.2e}"
            for k in sizes
        ],
        *graph_lines(model_doc),
        "- `model.json`: architecture, input encoding (incl. depth scale), I/O names; "
        "`GIModel` checks the ONNX file against it.",
        "",
        f"Metrics source: `{quality_csv.name}` (run {rows[0]['run_id'] if rows else '?'}).",
    ]


def graph_lines(model_doc: dict) -> list[str]:
    """The card's line on the graph form of the files (``gigan_local.subpixel``), if they have one."""
    from gigan_local.subpixel import GRAPH_NAME, MIN_SIDE  # onnx loads only when a card is written

    if model_doc.get("graph") != GRAPH_NAME:
        return []

    line = (
        f"- Graph: each nearest 2x resize + 3x3 conv on an input of at least {MIN_SIDE} px a side is exported as "
        "sub-pixel phase convolutions + DepthToSpace (`gigan_local.subpixel`: the same function; all but the "
        "outermost do 4/9 of the multiply-adds)"
    )
    rewrite = model_doc.get("graph_rewrite")
    if rewrite:  # an export rewritten in place (python -m gigan_local.rewrite_cli)
        diffs = ", ".join(f"{k} {v:.2e}" for k, v in rewrite["max_abs_diff_vs_resize_graph"].items())
        line += f"; rewritten after export, max |rewritten − resize graph| on a random input: {diffs}"
    return [line + "."]


#: SSIM per scene of the model and of DI alone (the card's table, as bars).
FIGURE = Figure(
    "model_card",
    (
        Chart(
            lambda rows: [flat(r) for r in rows if matches(r, "ssim") and r["scene"] != "all"],
            "scene",
            series="{system}",
            kind="bar",
            ylabel="mean SSIM on held-out frames (tone-mapped)",
        ),
    ),  # fmt: skip
)


def bench(quality: Bench) -> Bench:
    """``bench model-card``, scoring the small model it makes with ``quality`` (``bench quality``;
    :mod:`bench.registry` hands it in: benches import no bench)."""
    return Bench(
        "model-card",
        ModelCardConfig,
        partial(measure, quality=quality),
        help="MODEL_CARD.md for an exported model from its run, export and quality results.",
        parts=(FIGURE,),
    )
