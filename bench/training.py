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

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.common import train_small, training_minutes
from bench.runner import Bench
from gicore.error_policy import UserError
from gicore.results import Results, read_rows


@dataclass(frozen=True)
class TrainingBenchConfig:
    """Which runs to plot, and the small runs to train first when asked."""

    #: gigan-train run folders to compare (labelled by folder name).
    runs: tuple[Path, ...] = field(default=(), metadata={"min_len": 0})
    #: When set, first train one small GIGAN per --widths for this many steps (into <out>/runs) and plot it too.
    train_steps: int | None = None
    #: Generator widths (ngf) of the runs trained here.
    widths: tuple[int, ...] = (8, 16)
    #: Scenes whose small datasets (rendered into <out>/dataset) the runs trained here learn from.
    scenes: tuple[str, ...] = ("lung_plane",)

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
        train_small(cfg.scenes, cfg.widths, cfg.train_steps, res) if cfg.train_steps is not None else []
    )
    for run_dir in runs:
        config = json.loads((run_dir / "config.json").read_text())["train"]
        with (run_dir / "metrics.csv").open(newline="") as fh:
            for row in csv.DictReader(fh):
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


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Validation SSIM and training L1 against step, and validation SSIM against training minutes."""
    from gicore.plotting import plt, save

    rows = read_rows(csv_path)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4))
    for run_id in dict.fromkeys(r["system"] for r in rows):
        curves = {
            m: sorted((r["config"]["step"], r["value"]) for r in rows if r["system"] == run_id and r["metric"] == m)
            for m in ("val_ssim", "train_G_L1", "train_step_seconds")
        }
        for ax, metric in zip(axes, ("val_ssim", "train_G_L1")):
            if curves[metric]:
                ax.plot(*zip(*curves[metric]), label=run_id)
        if curves["val_ssim"] and curves["train_step_seconds"]:
            steps, ssim = zip(*curves["val_ssim"])
            axes[2].plot(np.asarray(training_minutes(curves["train_step_seconds"], steps)), ssim, label=run_id)
    axes[0].set_ylabel("validation SSIM (tone-mapped, full frames)")
    axes[1].set_ylabel("training L1 ([-1, 1] units)")
    axes[1].set_yscale("log")
    for ax in axes[:2]:
        ax.set_xlabel("optimizer step (critic steps for GIGAN)")
    axes[2].set_xlabel("training compute [min] (summed step times, as logged)")
    axes[2].set_ylabel("validation SSIM")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    return [save(fig, out_dir / "training.png")]


BENCH = Bench(
    "training",
    TrainingBenchConfig,
    measure,
    plot,
    help="Learning curves of training runs: validation SSIM and training L1 against step and against training minutes.",
)
