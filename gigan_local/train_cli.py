"""``gigan-train``: train GIGAN or a baseline on dataset folders (thin wrapper over :func:`train`)."""

from __future__ import annotations

from dataclasses import replace
from enum import Enum
from pathlib import Path
from typing import Optional

import typer

from gigan_local.config import BUDGET_FIELDS, TrainConfig
from gigan_local.train import CHECKPOINT, TrainingDiverged, read_run_config, train

app = typer.Typer(add_completion=False, help="Train GIGAN, Deep Shading or Deep Illumination on gicore dataset folders.")


class ModelName(str, Enum):
    gigan = "gigan"
    deep_shading = "deep_shading"
    deep_illumination = "deep_illumination"


@app.command()
def main(
    datasets: Optional[list[Path]] = typer.Argument(None, help="Dataset folders (made by gicore-dataset); not needed with --resume."),
    out: Path = typer.Option(..., "--out", help="Run folder: config.json, checkpoint.pt, metrics.csv."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its checkpoint."),
    model: Optional[ModelName] = typer.Option(None, help="Which model to train (default: gigan)."),
    buffers: Optional[str] = typer.Option(None, help="Comma-separated input buffers (default: di,albedo,normal,depth)."),
    ngf: Optional[int] = typer.Option(None, help="Generator width (default: 64)."),
    ndf: Optional[int] = typer.Option(None, help="Critic width (default: same as --ngf)."),
    n_down: Optional[int] = typer.Option(None, help="Generator down-samplings (default: from the training size)."),
    crop: Optional[int] = typer.Option(None, help="Train on random crops of this size (validation uses whole frames)."),
    batch_size: Optional[int] = typer.Option(None, help="Batch size (default: 8)."),
    lr: Optional[float] = typer.Option(None, help="Adam learning rate (default: 2e-4)."),
    n_critic: Optional[int] = typer.Option(None, help="GIGAN critic steps per generator step (default: 1)."),
    seed: Optional[int] = typer.Option(None, help="Random seed (default: 0)."),
    epochs: Optional[int] = typer.Option(None, help="Stop after this many epochs (default: 100)."),
    max_steps: Optional[int] = typer.Option(None, help="Stop after this many steps in all."),
    max_minutes: Optional[float] = typer.Option(None, help="Stop (validated and checkpointed) within this many minutes of wall time."),
    max_val_frames: Optional[int] = typer.Option(None, help="Validate on at most this many frames."),
    checkpoint_every: Optional[int] = typer.Option(None, help="Also checkpoint every N steps (0: epoch ends only) (default: 500)."),
    run_id: Optional[str] = typer.Option(None, help="Run name in metrics.csv (default: the --out folder name)."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
    cache_frames: bool = typer.Option(True, help="Keep encoded frames in memory (~3.4 MB per 256² frame); faster, same results."),
) -> None:
    """Train a model. With --resume, options left out keep the saved values, except the budget options
    (--epochs, --max-steps, --max-minutes, --max-val-frames, --checkpoint-every), which bound this
    invocation and take their defaults when left out."""
    budget = {"epochs": epochs, "max_steps": max_steps, "max_minutes": max_minutes, "max_val_frames": max_val_frames, "checkpoint_every": checkpoint_every}
    settings = {
        "datasets": [str(d) for d in datasets] if datasets else None,
        "model": model.value if model else None,
        "buffers": [b.strip() for b in buffers.split(",") if b.strip()] if buffers else None,
        "ngf": ngf, "ndf": ndf, "n_down": n_down, "crop": crop, "batch_size": batch_size, "lr": lr,
        "n_critic": n_critic, "seed": seed, "run_id": run_id,
    }
    given = {k: v for k, v in (settings | budget).items() if v is not None}
    try:
        if resume:
            saved, _ = read_run_config(out)
            changed = {k: v for k, v in given.items() if k not in BUDGET_FIELDS and v != getattr(saved, k)}
            if changed:
                raise ValueError(f"--resume may change only {list(BUDGET_FIELDS)}; drop {sorted(changed)} or start a new run in another --out")
            # Budgets bound this invocation: those not given take their defaults, not the saved values.
            defaults = TrainConfig()
            cfg = replace(saved, **({f: getattr(defaults, f) for f in BUDGET_FIELDS} | given))
        else:
            if not datasets:
                raise ValueError("give at least one dataset folder (or --resume an existing run)")
            cfg = TrainConfig(**given)
        result = train(cfg, out, resume=resume, progress=progress, cache_frames=cache_frames)
    except TrainingDiverged as e:
        typer.echo(f"error: {e}", err=True)
        raise typer.Exit(2)
    except (ValueError, FileNotFoundError, FileExistsError, KeyError) as e:
        typer.echo(f"error: {e}", err=True)
        raise typer.Exit(1)
    metrics = ", ".join(f"{k} {v:.4g}" for k, v in result.val_metrics.items())
    typer.echo(f"stopped ({result.stop_reason}) at step {result.step}, epoch {result.epoch}; val {metrics}; checkpoint {out / CHECKPOINT}")
