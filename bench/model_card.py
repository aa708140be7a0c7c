"""`bench model-card`: the card of an exported model (``MODEL_CARD.md``, :mod:`gigan_local.model_card`).

The card is written from the training run, the export and a ``bench quality`` CSV into the export folder
(it travels with the model); here its numbers also go to the tidy CSV, and the plot compares the model's
per-scene SSIM with DI alone.

On a fresh checkout (``--quick`` without ``--run``) the whole chain runs here, small: a GIGAN trained for
``--train-steps`` on the small dataset of ``--scenes`` (``bench training``'s runs), exported into
``<out>/export/<run>``, scored by ``bench quality`` on the same datasets into ``<out>/quality``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from functools import partial
from pathlib import Path

from bench.runner import Bench, execute
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.present.declarations import Chart, Figure, flat, matches
from gicore.results import Results, read_rows
from gigan_local.model_card import ModelCard
from gigan_local.train_small import train_small


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
        [run] = train_small(cfg.scenes, (cfg.width,), cfg.train_steps, res.out, res.seed)
        dataset_command = (
            f"bench model-card --quick: gigan_local.train_small.QUICK_DATASET of {', '.join(cfg.scenes)} "
            f"into {res.out / 'dataset'}"
        )
        train_command = (
            f"bench model-card --quick: gigan_local.train_small.train_small, GIGAN ngf {cfg.width}, "
            f"{cfg.train_steps} steps"
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
    card = ModelCard.read(run, export, read_rows(quality_csv), cfg.system, quality_csv)
    _record(res, card)
    res.files.append(card.write(dataset_command, train_command))


def _record(res: Results, card: ModelCard) -> None:
    """The card's numbers as tidy rows: training, validation, the quality CSV's means (and median inference
    time) of the model and of DI alone, the file sizes."""
    model_name, run, training, system = card.export_dir.name, card.run_dir.name, card.training, card.system
    res.add(system=model_name, scene="all", metric="training_steps", value=training.last_step, unit="count",
            run=run)  # fmt: skip
    res.add(system=model_name, scene="all", metric="training_time", value=training.compute_min, unit="min",
            stat="sum", run=run)  # fmt: skip
    for metric, value in training.val.items():
        unit = "dB" if metric == "psnr" else "1"
        res.add(system=model_name, scene="all", metric=f"val_{metric}", value=value, unit=unit,
                step=training.last_step)  # fmt: skip
    for r in card.rows:
        if r["system"] in (system, "di_only") and (
            r["stat"] == "mean" or r["metric"] == "inference_time" and r["stat"] == "median"
        ):
            res.add(system=model_name if r["system"] == system else "di_only", scene=r["scene"], metric=r["metric"],
                    value=r["value"], unit=r["unit"], stat=r["stat"], source=str(card.quality_source),
                    source_run=r["run_id"])  # fmt: skip
    for precision, mib in card.sizes.items():
        res.add(system=model_name, scene="all", metric="file_size", value=mib, unit="MiB", precision=precision)


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
