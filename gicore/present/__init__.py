"""What the benches show, declared once (:mod:`gicore.present.declarations`) and rendered to Markdown
(:mod:`gicore.present.markdown`), the dashboard's HTML and page (:mod:`gicore.present.html`) and figures
(:mod:`gicore.present.charts`: PNG and SVG from one matplotlib drawing); a sheet of images as one PNG
(:mod:`gicore.present.sheet`). :func:`write_files` writes a bench run's own: ``<bench>.md`` (every table) and
each figure's PNG and SVG beside the CSV."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from gicore.fileio import atomic_write_bytes
from gicore.present import charts
from gicore.present.declarations import Figure, Part, Rows
from gicore.present.markdown import tables_text


def write_files(name: str, parts: Sequence[Part], rows: Rows, out: Path) -> list[Path]:
    """``<out>/<name>.md`` with every table of ``parts`` (none without tables), and ``<figure>.png`` and
    ``.svg`` for each figure that has points; the paths written."""
    written = []
    md = tables_text(parts, rows, 2)
    if md:
        written.append(out / f"{name}.md")
        atomic_write_bytes(written[-1], (md + "\n").encode())
    for figure in (p for p in parts if isinstance(p, Figure)):
        png, svg = out / f"{figure.name}.png", out / f"{figure.name}.svg"
        drawn = charts.render(figure, rows, png)
        if drawn:
            atomic_write_bytes(svg, drawn.encode())
            written += [png, svg]
    return written
