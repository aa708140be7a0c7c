"""The model card: ``MODEL_CARD.md`` in an exported model's folder, the model's own documentation.

Every number on it comes from files the project produced: the training run (``config.json``,
``metrics.csv``), the export (``model.json``, the files' sizes) and the per-scene rows of a
``bench quality`` CSV, handed in as plain data (``gicore.results.read_rows``'s dicts). Nothing is typed
by hand, so the card stays true to the files it travels with.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gicore.error_policy import UserError
from gicore.metrics import LF_SIGMA

#: The card's file name in the export folder.
CARD_NAME = "MODEL_CARD.md"
#: Where the logged step times were measured, by the run's last ``--device``.
STEP_WHERE = {"cpu": "on this machine's CPU", "cuda": "on the CUDA GPU it trained on (not this machine)"}
#: How the card names each U-Net up-sampling (``NetworkConfig.upsample``; exports older than it are transposed).
UPSAMPLING_WORDS = {
    "transposed": "4x4 stride-2 transposed-conv up-sampling",
    "resize": "nearest 2x resize + 3x3 conv up-sampling",
}


def training_minutes(step_seconds: list[tuple[int, float]], steps: tuple[int, ...] | list[int]) -> list[float]:
    """Training minutes spent up to each of ``steps``, from (step, mean step seconds since the previous
    row) rows of a run's ``metrics.csv``; validation and checkpoint time is not counted. Steps past the last
    row extrapolate at its rate (a run stopped before its next train row)."""
    ends = np.array([0] + [s for s, _ in step_seconds], dtype=float)
    cumulative = np.concatenate([[0.0], np.cumsum(np.diff(ends) * np.array([v for _, v in step_seconds]))])
    last_rate = step_seconds[-1][1]
    return [float(np.interp(s, ends, cumulative) + max(0, s - ends[-1]) * last_rate) / 60.0 for s in steps]


@dataclass(frozen=True)
class TrainingRun:
    """What a gigan-train run folder says about the model: its train config and metrics rows, the last step,
    the logged step times (s) and their sum (min), and the validation metrics at the last step."""

    train: dict
    metrics: list[dict[str, str]]
    last_step: int
    step_s: list[float]
    compute_min: float
    val: dict[str, float]

    @staticmethod
    def files(run_dir: Path) -> tuple[dict, list[dict[str, str]]]:
        """The run folder's train config (``config.json``'s ``train``) and ``metrics.csv`` rows, as written (no
        rows yet for a run stopped before its first log)."""
        train = json.loads((run_dir / "config.json").read_text())["train"]
        with (run_dir / "metrics.csv").open(newline="") as fh:
            return train, list(csv.DictReader(fh))

    @classmethod
    def read(cls, run_dir: Path) -> TrainingRun:
        train, metrics = cls.files(run_dir)
        if not metrics:
            raise UserError(
                f"{run_dir / 'metrics.csv'} has no rows: the run stopped before its first log",
                "resume it with gigan-train --resume, or give a run that has trained",
            )
        last_step = max(int(r["step"]) for r in metrics)
        step_rows = sorted((int(r["step"]), float(r["value"])) for r in metrics if r["metric"] == "step_seconds")
        compute_min = training_minutes(step_rows, [last_step])[0] if step_rows else float("nan")
        val = {r["metric"]: float(r["value"]) for r in metrics if r["split"] == "val" and int(r["step"]) == last_step}
        return cls(train, metrics, last_step, [v for _, v in step_rows], compute_min, val)


@dataclass(frozen=True)
class ModelCard:
    """What a model's card states: its run and export folders as read, and the quality rows that scored it
    (as ``system``, read from ``quality_source``) beside DI alone (``di_only``)."""

    run_dir: Path
    export_dir: Path
    training: TrainingRun
    model_doc: dict
    #: MiB of each exported file, by precision (``model.json``'s ``files``).
    sizes: dict[str, float]
    rows: list[dict]
    system: str
    quality_source: Path

    @classmethod
    def read(cls, run_dir: Path, export_dir: Path, rows: list[dict], system: str, quality_source: Path) -> ModelCard:
        """The card of the model trained in ``run_dir`` and exported to ``export_dir``; refuses quality rows
        it cannot state as one set of numbers."""
        _check_quality_rows(rows, system, quality_source)
        model_doc = json.loads((export_dir / "model.json").read_text())
        sizes = {k: (export_dir / v).stat().st_size / 2**20 for k, v in model_doc["files"].items()}
        return cls(run_dir, export_dir, TrainingRun.read(run_dir), model_doc, sizes, rows, system, quality_source)

    def lines(self, dataset_command: str, train_command: str) -> list[str]:
        """The card's Markdown lines, quoting the commands that rendered its data and trained it."""
        return [
            *_model_lines(self.export_dir.name, self.model_doc, self.training, dataset_command, train_command),
            *_scene_lines(self.rows, self.system),
            *_file_lines(self.model_doc, self.sizes, self.quality_source, self.rows),
        ]

    def write(self, dataset_command: str, train_command: str) -> Path:
        """Write the card into the export folder; returns its path."""
        card = self.export_dir / CARD_NAME
        card.write_text("\n".join(self.lines(dataset_command, train_command)) + "\n")
        return card


def _check_quality_rows(rows: list[dict], system: str, source: Path) -> None:
    """Refuse rows with none of ``system``, or that score it on several renderers' inputs."""
    if not any(r["system"] == system for r in rows):
        raise UserError(
            f"quality CSV {source} has no rows of system {system!r}",
            "give the model's name in that CSV (`bench model-card --system`)",
        )
    # a card states one set of numbers: rows scored on several renderers' inputs would mix them per cell
    renderers = sorted({r["config"].get("renderer", "mitsuba") for r in rows if r["system"] == system})
    if len(renderers) > 1:
        raise UserError(
            f"quality CSV {source} scores {system!r} on the inputs of renderers {', '.join(renderers)}",
            "score the model with one `bench quality --renderers R` for its card",
        )


def _output_words(albedo_floor: float | None) -> str:
    """What the model's output is: the GI image, or its shading (albedo-demodulated)."""
    if albedo_floor is None:
        return "output: the path-traced GI image, tone-mapped to [-1, 1] (`gicore.tonemap`). "
    return (
        f"output: the path-traced GI image's shading (divided by the first hit's albedo, floor {albedo_floor:g}; "
        "the DI input likewise), tone-mapped to [-1, 1] (`gicore.tonemap`); the client multiplies the albedo back. "
    )


def _model_lines(
    name: str, model_doc: dict, training: TrainingRun, dataset_command: str, train_command: str
) -> list[str]:
    """The card's title, the generator, its data and its training."""
    train, val, step_s = training.train, training.val, training.step_s
    return [
        f"# Model card: {name}",
        "",
        f"Generator `{model_doc['model']}` (U-Net, ngf {model_doc['ngf']}, {model_doc['n_down']} down-samplings, "
        f"{UPSAMPLING_WORDS[model_doc.get('network', {}).get('upsample', 'transposed')]}), "
        f"inputs {model_doc['input']['buffers']} ({model_doc['in_channels']} channels) at {model_doc['resolution']}², "
        + _output_words(model_doc["input"].get("albedo_floor"))
        + f"One model for the {len(train['datasets'])} scene(s) of its training data.",
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
    """The card's table of the quality rows' metrics per scene, the model's beside DI alone's."""

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


def _file_lines(model_doc: dict, sizes: dict[str, float], quality_source: Path, rows: list[dict]) -> list[str]:
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
        f"Metrics source: `{quality_source.name}` (run {rows[0]['run_id'] if rows else '?'}).",
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
