"""`bench training`: learning curves of training runs (``gigan-train`` folders), from their metrics.csv.

Collects every run's validation metrics and training losses into one tidy CSV and plots validation
SSIM and training L1 against step, one line per run, so unstable adversarial training is visible; and
validation SSIM against training compute time (the logged step times summed), the axis on which model
widths compete for a fixed budget. Step times are as logged: runs that shared the CPU with other
runs report slower steps than they would alone.

On a fresh checkout there are no runs to compare, so ``--quick`` trains small GIGAN runs itself (one
per ``--widths``, ``--train-steps`` steps on the small datasets of ``--scenes``, into ``<out>/runs``;
rerunning resumes them) and plots those: a real, if tiny, width comparison.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bench.runner import Bench
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.present.declarations import Chart, Figure, Rows, matches, pick, unique
from gicore.results import Results
from gigan_local.model_card import TrainingRun, training_minutes
from gigan_local.train_small import train_small


@dataclass(frozen=True)
class TrainingBenchConfig:
    """Which runs to plot, and the small runs to train first when asked."""

    #: gigan-train run folders to compare (labelled by folder name).
    runs: tuple[Path, ...] = field(default=(), metadata={"min_len": 0})
    #: When set, first train one small GIGAN per --widths for this many steps (into <out>/runs) and plot it too.
    train_steps: int | None = None
    #: Generator widths (ngf) of the runs trained here.
    widths: tuple[int, ...] = (8, 16)
    scenes: tuple[str, ...] = option_groups.scenes(
        note="the runs trained here learn from their small datasets, rendered into <out>/dataset"
    )

    @classmethod
    def quick(cls) -> TrainingBenchConfig:
        return cls(train_steps=60)

    def check(self) -> None:
        if not self.runs and self.train_steps is None:
            raise UserError(
                "--runs is empty: no training runs to plot",
                "give --runs RUN[,RUN...] (gigan-train folders), or --quick to train small runs here",
            )
        for run_dir in self.runs:
            for name in ("metrics.csv", "config.json"):
                if not (run_dir / name).is_file():
                    raise UserError(f"--runs {run_dir}: {run_dir / name} is missing", "give gigan-train run folders")


def measure(cfg: TrainingBenchConfig, res: Results) -> None:
    runs = list(cfg.runs) + (
        train_small(cfg.scenes, cfg.widths, cfg.train_steps, res.out, res.seed) if cfg.train_steps is not None else []
    )
    for run_dir in runs:
        config, metrics = TrainingRun.files(run_dir)
        for row in metrics:
            res.add(
                system=run_dir.name,
                scene="all",
                metric=f"{row['split']}_{row['metric']}",
                value=float(row["value"]),
                unit=row["unit"],
                step=int(row["step"]),
                epoch=int(row["epoch"]),
                model=row["model"],
                ngf=config["ngf"],
                n_critic=config["n_critic"],
            )


def ssim_by_minutes(rows: Rows) -> list[dict]:
    """Each run's validation SSIM at the training minutes it had spent by then."""
    out = []
    for run in unique(r["system"] for r in rows):
        ssim = sorted((r["config"]["step"], r["value"]) for r in rows if matches(r, "val_ssim") and r["system"] == run)
        times = sorted(
            (r["config"]["step"], r["value"]) for r in rows if matches(r, "train_step_seconds") and r["system"] == run
        )
        if ssim and times:
            minutes = training_minutes(times, [step for step, _ in ssim])
            out += [{"system": run, "minutes": m, "value": v} for m, (_, v) in zip(minutes, ssim)]
    return out


STEP = "optimizer step (critic steps for GIGAN)"
PARTS = (
    Figure(
        "training",
        (
            Chart(
                pick("val_ssim"),
                "step",
                series="{system}",
                xlabel=STEP,
                ylabel="validation SSIM (tone-mapped, full frames)",
            ),
            Chart(
                pick("train_G_L1"),
                "step",
                series="{system}",
                xlabel=STEP,
                ylabel="training L1 ([-1, 1] units)",
                ylog=True,
            ),
            Chart(
                ssim_by_minutes,
                "minutes",
                series="{system}",
                ylabel="validation SSIM",
                xlabel="training compute [min] (summed step times, as logged)",
            ),
        ),  # fmt: skip
    ),
)


BENCH = Bench(
    "training",
    TrainingBenchConfig,
    measure,
    help="Learning curves of training runs: validation SSIM and training L1 against step and against training minutes.",
    parts=PARTS,
)
