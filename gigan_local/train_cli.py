"""``gigan-train``: train GIGAN or a baseline on dataset folders (thin wrapper over :func:`train`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Literal

import typer

from gicore.cli import UserError, entry_point, require_positive
from gigan_local.config import BUDGET_FIELDS, DEVICES, MODELS, UPSAMPLINGS, TrainConfig, read_run_config

app = typer.Typer(
    add_completion=False, help="Train GIGAN, Deep Shading or Deep Illumination on gicore dataset folders."
)


def _config(**given: object) -> TrainConfig:
    """The training config of the given options; an option value the config refuses is a user error."""
    try:
        return TrainConfig(**given)
    except ValueError as e:
        raise UserError(f"invalid training option: {e}", "see 'gigan-train --help'") from None


@app.command()
def train_command(
    out: Annotated[Path, typer.Option("--out", help="Run folder: config.json, checkpoint.pt, metrics.csv.")],
    datasets: Annotated[
        list[Path] | None, typer.Argument(help="Dataset folders (made by gicore-dataset); not needed with --resume.")
    ] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue the run in --out from its checkpoint.")] = False,
    model: Annotated[Literal[MODELS] | None, typer.Option(help="Which model to train (default: gigan).")] = None,  # type: ignore[valid-type]
    buffers: Annotated[
        str | None, typer.Option(help="Comma-separated input buffers (default: di,albedo,normal,depth).")
    ] = None,
    ngf: Annotated[int | None, typer.Option(min=1, help="Generator width (default: 64).")] = None,
    ndf: Annotated[int | None, typer.Option(min=1, help="Critic width (default: same as --ngf).")] = None,
    n_down: Annotated[
        int | None, typer.Option(min=1, help="Generator down-samplings (default: from the training size).")
    ] = None,
    upsample: Annotated[
        Literal[UPSAMPLINGS] | None,  # type: ignore[valid-type]
        typer.Option(
            help="U-Net up-sampling: transposed conv (pix2pix, the paper) or nearest resize + 3x3 conv (default: transposed)."
        ),
    ] = None,
    critic_condition: Annotated[
        bool | None,
        typer.Option(
            "--critic-condition/--no-critic-condition",
            help="Give the critic the generator input beside the image (default: on).",
        ),
    ] = None,
    crop: Annotated[
        int | None, typer.Option(min=1, help="Train on random crops of this size (validation uses whole frames).")
    ] = None,
    batch_size: Annotated[int | None, typer.Option(min=1, help="Batch size (default: 8).")] = None,
    lr: Annotated[float | None, typer.Option(help="Adam learning rate, > 0 (default: 2e-4).")] = None,
    n_critic: Annotated[
        int | None, typer.Option(min=1, help="GIGAN critic steps per generator step (default: 1).")
    ] = None,
    critic_warmup: Annotated[
        int | None, typer.Option(min=0, help="GIGAN critic-only steps before the generator's first step (default: 0).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed (default: 0).")] = None,
    epochs: Annotated[int | None, typer.Option(min=1, help="Stop after this many epochs (default: 100).")] = None,
    max_steps: Annotated[int | None, typer.Option(min=0, help="Stop after this many steps in all.")] = None,
    max_minutes: Annotated[
        float | None, typer.Option(help="Stop (validated and checkpointed) within this many minutes of wall time, > 0.")
    ] = None,
    max_val_frames: Annotated[int | None, typer.Option(min=1, help="Validate on at most this many frames.")] = None,
    checkpoint_every: Annotated[
        int | None, typer.Option(min=0, help="Also checkpoint every N steps (0: epoch ends only) (default: 500).")
    ] = None,
    device: Annotated[
        Literal[DEVICES] | None,  # type: ignore[valid-type]
        typer.Option(help="Train on the CPU or a CUDA GPU (default: cpu); checkpoints load on either."),
    ] = None,
    run_id: Annotated[
        str | None, typer.Option(help="Run name in metrics.csv (default: the --out folder name).")
    ] = None,
    init_generator: Annotated[
        Path | None,
        typer.Option(
            help="Fine-tune this exported model (gigan-export's ONNX, model.json beside it) instead of random weights."
        ),
    ] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
    cache_frames: Annotated[
        bool, typer.Option(help="Keep encoded frames in memory (~3.4 MB per 256² frame); faster, same results.")
    ] = True,
) -> None:
    """Train a model. With --resume, options left out keep the saved values, except the budget options
    (--epochs, --max-steps, --max-minutes, --max-val-frames, --checkpoint-every, --device), which bound
    this invocation and take their defaults when left out."""
    for name, value in (("--lr", lr), ("--max-minutes", max_minutes)):
        if value is not None:
            require_positive(name, value)
    budget = {
        "epochs": epochs,
        "max_steps": max_steps,
        "max_minutes": max_minutes,
        "max_val_frames": max_val_frames,
        "checkpoint_every": checkpoint_every,
        "device": device,
    }
    settings = {
        "datasets": [str(d) for d in datasets] if datasets else None,
        "model": model,
        "buffers": [b.strip() for b in buffers.split(",") if b.strip()] if buffers is not None else None,
        "ngf": ngf,
        "ndf": ndf,
        "n_down": n_down,
        "upsample": upsample,
        "critic_condition": critic_condition,
        "crop": crop,
        "batch_size": batch_size,
        "lr": lr,
        "n_critic": n_critic,
        "critic_warmup": critic_warmup,
        "seed": seed,
        "run_id": run_id,
        "init_generator": str(init_generator) if init_generator is not None else None,
    }
    given = {k: v for k, v in (settings | budget).items() if v is not None}
    if resume:
        saved, _ = read_run_config(out)
        changed = {k: v for k, v in given.items() if k not in BUDGET_FIELDS and v != getattr(saved, k)}
        if changed:
            raise UserError(
                f"--resume may change only {list(BUDGET_FIELDS)}, not {sorted(changed)}",
                "drop those options or start a new run in another --out",
            )
        # Budgets bound this invocation: those not given take their defaults, not the saved values.
        defaults = TrainConfig()
        cfg = replace(saved, **({f: getattr(defaults, f) for f in BUDGET_FIELDS} | given))
    else:
        if not datasets:
            raise UserError(
                "no dataset folders given",
                "give at least one folder made by gicore-dataset (or --resume an existing run)",
            )
        cfg = _config(**given)
    from gigan_local.train import CHECKPOINT, train  # torch loads only once the options are known to be valid

    result = train(cfg, out, resume=resume, progress=progress, cache_frames=cache_frames)
    metrics = ", ".join(f"{k} {v:.4g}" for k, v in result.val_metrics.items())
    typer.echo(
        f"stopped ({result.stop_reason}) at step {result.step}, epoch {result.epoch}; val {metrics}; checkpoint {out / CHECKPOINT}"
    )


main = entry_point(app, resume="the last checkpoint in --out is kept: run the same command with --resume to continue")

if __name__ == "__main__":
    main()
