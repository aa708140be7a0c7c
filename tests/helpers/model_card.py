"""A model's run and export folders as small as a model card reads them (no training, no ONNX)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

#: The validation metrics the run logs at its last step (4).
VAL = {"ssim": 0.9, "psnr": 25.0, "rmse": 0.05, "lf_error": 0.0123}


def write_run_and_export(run: Path, export: Path, resolution: int) -> None:
    """A gigan-train run folder (config.json; metrics.csv: :data:`VAL` and one 0.5 s step time at step 4,
    epoch 1) and a gigan-export folder (a 1 KiB fp32 file and its model.json)."""
    run.mkdir(parents=True)
    export.mkdir(parents=True)
    train = {"datasets": ["data/synthetic"], "model": "gigan", "lambda_L1": 100, "lambda_gp": 10, "n_critic": 5}
    train |= {"lr": 2e-4, "beta1": 0.5, "beta2": 0.999, "batch_size": 8, "crop": 64, "seed": 0, "max_val_frames": 2}
    (run / "config.json").write_text(json.dumps({"train": train}))
    with (run / "metrics.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["run_id", "model", "epoch", "step", "split", "metric", "value", "unit"])
        for metric, value in VAL.items():
            writer.writerow(["run", "gigan", 1, 4, "val", metric, value, "1"])
        writer.writerow(["run", "gigan", 1, 4, "train", "step_seconds", 0.5, "s"])
    (export / "model.onnx").write_bytes(b"x" * 1024)
    doc = {"model": "unet", "ngf": 8, "n_down": 6, "input": {"buffers": ["di"]}, "in_channels": 3}
    doc |= {"resolution": resolution, "files": {"fp32": "model.onnx"}, "max_abs_diff_vs_torch": {"fp32": 1e-6}}
    (export / "model.json").write_text(json.dumps(doc))
