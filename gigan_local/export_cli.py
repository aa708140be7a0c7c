"""``gigan-export``: export a training run's generator to ONNX (thin wrapper over :func:`export_onnx`).

Its options are derived from :class:`ExportConfig` (:mod:`gicore.options`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import typer

from gicore import option_groups
from gicore.error_policy import entry_point
from gicore.options import FRAMES, build_config, config_command, extra
from gigan_local.inference import MODEL_JSON

app = typer.Typer(
    add_completion=False,
    help="Export a trained generator to ONNX (fp32, fp16 weights, optionally int8) with model.json.",
)


@dataclass(frozen=True)
class ExportConfig:
    """What :func:`gigan_local.export.export_onnx` writes besides the fp32 model."""

    #: ONNX opset (torch's exporter writes 17 to 20).
    opset: int = field(default=17, metadata={"min": 17, "max": 20})
    #: Also write the fp16-weights variant.
    fp16: bool = True
    #: Also write a static int8 variant, calibrated on the run's training frames (its datasets must exist).
    int8: bool = False
    #: Training frames that calibrate the int8 activation ranges.
    calibration_frames: int = field(default=32, metadata=FRAMES)


def export_command(given: dict[str, Any], *, run: Path, out: Path) -> None:
    """Export, then report file sizes and the onnxruntime-vs-torch difference of each variant."""
    cfg = build_config(ExportConfig, given)
    from gigan_local.export import export_onnx  # torch loads only once the options are known to be valid

    result = export_onnx(
        run, out, opset=cfg.opset, fp16=cfg.fp16, int8=cfg.int8, calibration_frames=cfg.calibration_frames
    )
    for k, path in result.files.items():
        size = f"{path}: {result.sizes[k] / 2**20:.2f} MiB"
        if k == "int8":
            typer.echo(f"{size}, mean |int8 - fp32| on validation frames = {result.int8_mean_abs_diff:.2e}")
        else:
            typer.echo(f"{size}, max |onnxruntime - torch| = {result.max_abs_diff[k]:.2e}")
    typer.echo(f"config: {out / MODEL_JSON}")


RUN_HELP = "Training run folder (config.json + checkpoint.pt, made by gigan-train)."
config_command(
    app,
    ExportConfig,
    export_command,
    extras=[
        extra("run", Annotated[Path, typer.Argument(help=RUN_HELP)]),
        option_groups.out("model_fp32.onnx, model_fp16.onnx and model.json"),
    ],
)

main = entry_point(app, resume="each file in --out is either complete or absent: run the same command again")

if __name__ == "__main__":
    main()
