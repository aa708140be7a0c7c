"""Write a model card (Markdown) for an exported model from files the project produced.

Every number comes from the training run (``config.json``, ``metrics.csv``), the export (``model.json``,
file sizes) and a ``bench quality`` CSV; nothing is typed by hand.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from gicore.results import read_rows
from bench.training import training_minutes


def write_model_card(run_dir: Path, export_dir: Path, quality_csv: Path, system: str, dataset_command: str, train_command: str) -> Path:
    config = json.loads((run_dir / "config.json").read_text())
    train = config["train"]
    model_doc = json.loads((export_dir / "model.json").read_text())
    with (run_dir / "metrics.csv").open(newline="") as fh:
        metrics = list(csv.DictReader(fh))
    last_step = max(int(r["step"]) for r in metrics)
    step_rows = sorted((int(r["step"]), float(r["value"])) for r in metrics if r["metric"] == "step_seconds")
    step_s = [v for _, v in step_rows]
    compute_min = training_minutes(step_rows, [last_step])[0] if step_rows else float("nan")
    val = {r["metric"]: float(r["value"]) for r in metrics if r["split"] == "val" and int(r["step"]) == last_step}
    rows = read_rows(quality_csv)
    scenes = sorted({r["scene"] for r in rows})

    def cell(sys: str, scene: str, metric: str, stat: str = "mean") -> str:
        v = [r["value"] for r in rows if r["system"] == sys and r["scene"] == scene and r["metric"] == metric and r["stat"] == stat]
        digits = {"psnr": 2, "inference_time": 1}.get(metric, 4)
        return f"{v[0]:.{digits}f}" if v else "n/a"

    sizes = {k: (export_dir / v).stat().st_size / 2**20 for k, v in model_doc["files"].items()}
    lines = [
        f"# Model card: {export_dir.name}",
        "",
        f"Generator `{model_doc['model']}` (U-Net, ngf {model_doc['ngf']}, {model_doc['n_down']} down-samplings), "
        f"inputs {model_doc['input']['buffers']} ({model_doc['in_channels']} channels) at {model_doc['resolution']}², "
        "output: the path-traced GI image, tone-mapped to [-1, 1] (`gicore.tonemap`). One model for all five paper scenes.",
        "",
        "## Data",
        f"`{dataset_command}`",
        "",
        f"Datasets: {', '.join(Path(d).name for d in train['datasets'])} (train splits train, held-out val splits validate: "
        "validation frames come from a different camera trajectory).",
        "",
        "## Training",
        f"`{train_command}`",
        "",
        f"Loss: {train['model']} (λ_L1 {train['lambda_L1']}, λ_GP {train['lambda_gp']}, n_critic {train['n_critic']}), "
        f"Adam lr {train['lr']} β=({train['beta1']}, {train['beta2']}), batch {train['batch_size']}, random {train['crop']}² crops, seed {train['seed']}. "
        f"Stopped at optimizer step {last_step} (epoch {max(int(r['epoch']) for r in metrics)}); "
        f"median step time {sorted(step_s)[len(step_s) // 2]:.2f} s on this machine's CPU, {compute_min:.0f} min of steps in all "
        "(validation and checkpoints not counted; logged per epoch in metrics.csv). "
        f"Validation at the last step (first {train['max_val_frames']} val frames): SSIM {val.get('ssim', float('nan')):.4f}, "
        f"PSNR {val.get('psnr', float('nan')):.2f} dB, RMSE {val.get('rmse', float('nan')):.4f}.",
        "",
        "## Metrics per scene (`bench quality`, all held-out frames, tone-mapped, SPEC §3)",
        "",
        "| scene | SSIM | PSNR dB | RMSE | DI alone SSIM | median inference ms |",
        "|---|---|---|---|---|---|",
    ]
    for scene in scenes:
        lines.append(
            f"| {scene} | {cell(system, scene, 'ssim')} | {cell(system, scene, 'psnr')} | {cell(system, scene, 'rmse')} | "
            f"{cell('di_only', scene, 'ssim')} | {cell(system, scene, 'inference_time', 'median')} |"
        )
    lines += [
        "",
        "## Files",
        *[f"- `{model_doc['files'][k]}`: {k} weights, {sizes[k]:.2f} MiB, max |onnxruntime − torch| = {model_doc['max_abs_diff_vs_torch'][k]:.2e}" for k in sizes],
        "- `model.json`: architecture, input encoding (incl. depth scale), I/O names; `GIModel` checks the ONNX file against it.",
        "",
        f"Metrics source: `{quality_csv.name}` (run {rows[0]['run_id'] if rows else '?'}).",
    ]
    card = export_dir / "MODEL_CARD.md"
    card.write_text("\n".join(lines) + "\n")
    return card
