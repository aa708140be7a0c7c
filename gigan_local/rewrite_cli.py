"""``python -m gigan_local.rewrite_cli MODEL_DIR``: rewrite an export of a resize U-Net in place as
sub-pixel convolutions (:func:`gigan_local.export.rewrite_export`; ``gigan-export`` does it to every new export).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from gicore.error_policy import entry_point

app = typer.Typer(
    add_completion=False, help="Rewrite an exported resize U-Net's up-sampling as sub-pixel convolutions."
)


@app.command()
def rewrite(model_dir: Annotated[Path, typer.Argument(help="Folder written by gigan-export.")]) -> None:
    """Rewrite MODEL_DIR's ONNX files in place (the same function, a faster graph) and update its model.json."""
    from gigan_local.export import rewrite_export  # onnx loads only once the command line is parsed

    for k, diff in rewrite_export(model_dir).items():
        typer.echo(f"{model_dir}: {k} rewritten, max |new - old| on a random input = {diff:.2e}")


main = entry_point(app, resume="if model.json does not say graph 'subpixel', restore the folder's files and run again")

if __name__ == "__main__":
    main()
