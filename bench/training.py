"""`bench training`: learning curves of training runs (``gigan-train`` folders), from their metrics.csv.

Collects every run's validation metrics and training losses into one tidy CSV and plots validation
SSIM and training L1 against step, one line per run, so unstable adversarial training is visible; and
validation SSIM against training compute time (the logged step times summed), the axis on which model
widths compete for a fixed budget. Step times are as logged: runs that shared the CPU with other
runs report slower steps than they would alone.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from gicore.results import Results, read_rows


def run(runs: list[Path], out: Path) -> Path:
    res = Results("training", out, settings={"runs": [str(r) for r in runs]})
    for run_dir in runs:
        metrics = run_dir / "metrics.csv"
        if not metrics.is_file():
            raise FileNotFoundError(f"{metrics} is missing; is {run_dir} a gigan-train run folder?")
        config = json.loads((run_dir / "config.json").read_text())["train"]
        with metrics.open(newline="") as fh:
            for row in csv.DictReader(fh):
                res.add(
                    system=run_dir.name, scene="all", metric=f"{row['split']}_{row['metric']}", value=float(row["value"]), unit=row["unit"],
                    step=int(row["step"]), epoch=int(row["epoch"]), model=row["model"], ngf=config["ngf"], n_critic=config["n_critic"],
                )
    path = res.write()
    plot(path, out / "training.png")
    return path


def plot(csv_path: Path, png: Path) -> None:
    from gicore.plotting import plt, save

    rows = read_rows(csv_path)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4))
    for run_id in dict.fromkeys(r["system"] for r in rows):
        curves = {m: sorted((r["config"]["step"], r["value"]) for r in rows if r["system"] == run_id and r["metric"] == m) for m in ("val_ssim", "train_G_L1", "train_step_seconds")}
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
    save(fig, png)


def training_minutes(step_seconds: list[tuple[int, float]], steps: tuple[int, ...] | list[int]) -> list[float]:
    """Training minutes spent up to each of ``steps``, from (step, mean step seconds since the previous
    row) rows; validation and checkpoint time is not counted. Steps past the last row extrapolate at
    its rate (a run stopped before its next train row)."""
    ends = np.array([0] + [s for s, _ in step_seconds], dtype=float)
    cumulative = np.concatenate([[0.0], np.cumsum(np.diff(ends) * np.array([v for _, v in step_seconds]))])
    last_rate = step_seconds[-1][1]
    return [float(np.interp(s, ends, cumulative) + max(0, s - ends[-1]) * last_rate) / 60.0 for s in steps]
