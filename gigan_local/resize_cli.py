"""``python -m gigan_local.resize_cli MODEL_DIR --resolution R --out DIR``: an export's network for frames of
another side (:func:`gigan_local.export.resize_export`), e.g. Table 1 at 512² from the shipped 256² model. The
latency it gives is the network's at that side; its quality there is not that of a model trained there."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from gicore.error_policy import entry_point

app = typer.Typer(add_completion=False, help="Export an exported generator again for frames of another side.")


@app.command()
def resize(
    model_dir: Annotated[Path, typer.Argument(help="Folder written by gigan-export.")],
    resolution: Annotated[int, typer.Option(help="Side of the frames the new export takes, px.", min=16, max=4096)],
    out: Annotated[Path, typer.Option(help="Folder for the new ONNX files and model.json.")],
) -> None:
    """Write MODEL_DIR's model for RESOLUTION² frames into OUT, checked against torch on the same weights."""
    from gigan_local.export import resize_export  # onnx and torch load only once the command line is parsed

    for k, diff in resize_export(model_dir, out, resolution).items():
        typer.echo(f"{out}: {k} at {resolution}², max |onnxruntime - torch| on a random input = {diff:.2e}")


main = entry_point(app, resume="each file in --out is either complete or absent: run the same command again")

if __name__ == "__main__":
    main()
