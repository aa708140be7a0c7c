"""`bench training`: learning curves of training runs (``gigan-train`` folders), from their metrics.csv.

Collects every run's validation metrics and training losses into one tidy CSV and plots validation
SSIM and training L1 against step, one line per run, so unstable adversarial training is visible.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from bench.results import Results, read_rows


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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_rows(csv_path)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for run_id in dict.fromkeys(r["system"] for r in rows):
        for ax, metric in zip(axes, ("val_ssim", "train_G_L1")):
            pts = sorted((r["config"]["step"], r["value"]) for r in rows if r["system"] == run_id and r["metric"] == metric)
            if pts:
                ax.plot(*zip(*pts), label=run_id)
    axes[0].set_ylabel("validation SSIM (tone-mapped, full frames)")
    axes[1].set_ylabel("training L1 ([-1, 1] units)")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("optimizer step (critic steps for GIGAN)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)
