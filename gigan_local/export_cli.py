"""``gigan-export``: export a training run's generator to ONNX (thin wrapper over :func:`export_onnx`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from gicore.cli import entry_point
from gigan_local.inference import MODEL_JSON

app = typer.Typer(
    add_completion=False,
    help="Export a trained generator to ONNX (fp32, fp16 weights, optionally int8) with model.json.",
)


@app.command()
def export_command(
    run: Annotated[
        Path, typer.Argument(help="Training run folder (config.json + checkpoint.pt, made by gigan-train).")
    ],
    out: Annotated[Path, typer.Option("--out", help="Folder for model_fp32.onnx, model_fp16.onnx and model.json.")],
    opset: Annotated[int, typer.Option(min=17, help="ONNX opset (>= 17).")] = 17,
    fp16: Annotated[bool, typer.Option(help="Also write the fp16-weights variant.")] = True,
    int8: Annotated[
        bool,
        typer.Option(
            help="Also write a static int8 variant, calibrated on the run's training frames (its datasets must exist)."
        ),
    ] = False,
    calibration_frames: Annotated[
        int, typer.Option(min=1, help="Training frames that calibrate the int8 activation ranges.")
    ] = 32,
) -> None:
    """Export, then report file sizes and the onnxruntime-vs-torch difference of each variant."""
    from gigan_local.export import export_onnx  # torch loads only once the options are known to be valid

    result = export_onnx(run, out, opset=opset, fp16=fp16, int8=int8, calibration_frames=calibration_frames)
    for k, path in result.files.items():
        if k == "int8":
            typer.echo(
                f"{path}: {result.sizes[k] / 2**20:.2f} MiB, mean |int8 - fp32| on validation frames = {result.int8_mean_abs_diff:.2e}"
            )
        else:
            typer.echo(
                f"{path}: {result.sizes[k] / 2**20:.2f} MiB, max |onnxruntime - torch| = {result.max_abs_diff[k]:.2e}"
            )
    typer.echo(f"config: {out / MODEL_JSON}")


main = entry_point(app, resume="each file in --out is either complete or absent: run the same command again")

if __name__ == "__main__":
    main()
