"""``gigan-export``: export a training run's generator to ONNX (thin wrapper over :func:`export_onnx`)."""

from __future__ import annotations

from pathlib import Path

import typer

from gigan_local.export import MODEL_JSON, export_onnx

app = typer.Typer(add_completion=False, help="Export a trained generator to ONNX (fp32 and fp16 weights) with model.json.")


@app.command()
def main(
    run: Path = typer.Argument(..., help="Training run folder (config.json + checkpoint.pt, made by gigan-train)."),
    out: Path = typer.Option(..., "--out", help="Folder for model_fp32.onnx, model_fp16.onnx and model.json."),
    opset: int = typer.Option(17, help="ONNX opset (>= 17)."),
    fp16: bool = typer.Option(True, help="Also write the fp16-weights variant."),
) -> None:
    """Export, then report file sizes and the onnxruntime-vs-torch difference of each variant."""
    try:
        result = export_onnx(run, out, opset=opset, fp16=fp16)
    except (ValueError, FileNotFoundError) as e:
        typer.echo(f"error: {e}", err=True)
        raise typer.Exit(1)
    for k, path in result.files.items():
        typer.echo(f"{path}: {result.sizes[k] / 2**20:.2f} MiB, max |onnxruntime - torch| = {result.max_abs_diff[k]:.2e}")
    typer.echo(f"config: {out / MODEL_JSON}")
