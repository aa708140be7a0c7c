"""``gigan-train``: train GIGAN or a baseline on dataset folders (thin wrapper over :func:`train`).

Its options are derived from :class:`gigan_local.config.TrainConfig` (:mod:`gicore.options`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import typer

from gicore import option_groups
from gicore.error_policy import UserError, entry_point
from gicore.fileio import TMP_MARKER
from gicore.options import build_config, config_command, extra, parse_options
from gigan_local.config import BUDGET_FIELDS, CONFIG, TrainConfig, read_run_config

app = typer.Typer(
    add_completion=False, help="Train GIGAN, Deep Shading or Deep Illumination on gicore dataset folders."
)


#: What a training run's folder holds: gigan_local.train's CHECKPOINT and METRICS (importing it loads torch),
#: the config, and the lock a run holds; and temporary files (TMP_MARKER) of writes cut short.
RUN_FILES = frozenset({CONFIG, "checkpoint.pt", "metrics.csv", ".lock"})


def check_new_out(out: Path) -> None:
    """Refuse an ``--out`` holding anything but a training run's files: a new run would write among them (a
    folder holding a run is refused by the training itself, which offers --resume)."""
    if not out.is_dir():
        return
    others = sorted(p.name for p in out.iterdir() if p.name not in RUN_FILES and TMP_MARKER not in p.name)
    if others:
        shown = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
        raise UserError(
            f"--out {out} is not a training run (it holds {shown})",
            "give an empty or new folder, or --resume a run made by gigan-train",
        )


def train_command(given: dict[str, Any], *, out: Path, resume: bool, progress: bool, cache_frames: bool) -> None:
    """Train a model. With --resume, options left out keep the saved values, except the budget options
    (--epochs, --max-steps, --max-minutes, --max-val-frames, --checkpoint-every, --device), which bound
    this invocation and take their defaults when left out."""
    values = parse_options(TrainConfig, given)  # each option given, parsed and checked
    if resume:
        saved, _ = read_run_config(out)
        changed = {k: v for k, v in values.items() if k not in BUDGET_FIELDS and v != getattr(saved, k)}
        if changed:
            raise UserError(
                f"--resume may change only {list(BUDGET_FIELDS)}, not {sorted(changed)}",
                "drop those options or start a new run in another --out",
            )
        # Budgets bound this invocation: those not given take their defaults, not the saved values.
        defaults = TrainConfig()
        cfg = build_config(TrainConfig, given, replace(saved, **{f: getattr(defaults, f) for f in BUDGET_FIELDS}))
    else:
        if not values.get("datasets"):
            raise UserError(
                "no dataset folders given",
                "give at least one folder made by gicore-dataset (or --resume an existing run)",
            )
        check_new_out(out)
        cfg = build_config(TrainConfig, given)
    from gigan_local.train import CHECKPOINT, train  # torch loads only once the options are known to be valid

    result = train(cfg, out, resume=resume, progress=progress, cache_frames=cache_frames)
    metrics = ", ".join(f"{k} {v:.4g}" for k, v in result.val_metrics.items())
    typer.echo(
        f"stopped ({result.stop_reason}) at step {result.step}, epoch {result.epoch}; val {metrics};"
        f" checkpoint {out / CHECKPOINT}"
    )


config_command(
    app,
    TrainConfig,
    train_command,
    extras=[
        option_groups.out("the run: config.json, checkpoint.pt, metrics.csv"),
        extra(
            "resume",
            Annotated[bool, typer.Option("--resume", help="Continue the run in --out from its checkpoint.")],
            False,
        ),
        extra("progress", Annotated[bool, typer.Option(help="Show a progress bar.")], True),
        extra(
            "cache_frames",
            Annotated[
                bool, typer.Option(help="Keep encoded frames in memory (~3.4 MB per 256² frame); faster, same results.")
            ],
            True,
        ),
    ],
)

main = entry_point(app, resume="the last checkpoint in --out is kept: run the same command with --resume to continue")

if __name__ == "__main__":
    main()
