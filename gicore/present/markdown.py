"""Markdown: tables (the README's results blocks and each bench's ``<bench>.md``), figures drawn as PNG files and
linked, and where a results CSV's numbers come from."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from gicore.fileio import atomic_write_bytes
from gicore.present import charts
from gicore.present.declarations import Column, Figure, Image, Part, Rows, Table, fill, text, unique
from gicore.results import provenance_fields


def columns(table: Table, rows: Rows) -> tuple[Column, ...]:
    return table.columns(rows) if callable(table.columns) else table.columns


def groups(table: Table, derived: list[dict]) -> list[tuple[str, list[dict]]]:
    """(heading, rows) of each sub-table: one per value of ``table.group``, in order; one unnamed without it."""
    if not table.group:
        return [("", derived)]
    headings = [fill(table.group, r) for r in derived]
    return [(h, [r for r, g in zip(derived, headings) if g == h]) for h in unique(headings)]


def grid(cols: tuple[Column, ...], derived: list[dict]) -> str:
    """The Markdown table of ``derived`` (a ``|`` inside a cell escaped)."""

    def line(cells: Iterable[str]) -> str:
        return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"

    body = [line(fill(c.cell, r) for c in cols) for r in derived]
    return "\n".join([line(c.header for c in cols), "|---" * len(cols) + "|", *body])


def table_text(table: Table, rows: Rows, level: int) -> str:
    """``table`` as Markdown, its title a heading of ``level`` (its sub-tables one below); empty without rows."""
    derived = table.rows(rows)
    if not derived:
        return ""
    title, caption, notes = (text(t, rows) for t in (table.title, table.caption, table.notes))
    sub = level + 1 if title else level
    out = [f"{'#' * level} {title}"] if title else []
    out += [caption] if caption else []
    for heading, mine in groups(table, derived):
        out += [f"{'#' * sub} {heading}"] if heading else []
        out.append(grid(columns(table, rows), mine))
        note = fill(table.group_note, mine[0]) if table.group_note else ""
        out += [note] if note else []
    out += [notes] if notes else []
    return "\n\n".join(out)


def tables_text(parts: Iterable[Part], rows: Rows, level: int) -> str:
    """Every table of ``parts`` as Markdown, one after another."""
    shown = (table_text(p, rows, level) for p in parts if isinstance(p, Table))
    return "\n\n".join(t for t in shown if t)


def figure_links(name: str, parts: list[Part], rows: Rows, folder: Path, figures: Path, page: Path) -> str:
    """Each figure of ``parts`` drawn from ``rows`` (and each picture the bench wrote into ``folder``) as a PNG in
    ``figures/<name>/``, linked as a Markdown image relative to ``page``, the file the text goes into."""
    links = []
    for part in parts:
        if isinstance(part, Figure) and charts.render(part, rows, figures / name / f"{part.name}.png"):
            links.append(figures / name / f"{part.name}.png")
        elif isinstance(part, Image) and (folder / part.file).is_file():
            links.append(figures / name / part.file)
            links[-1].parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(links[-1], (folder / part.file).read_bytes())
    return "\n".join(f"![{t.stem}]({Path(os.path.relpath(t, page.parent)).as_posix()})" for t in links)


def provenance_line(csv_path: Path, where: str) -> str:
    """Where a results CSV's numbers come from, in one line: the command, date and machine from the provenance
    JSON beside it, and ``where`` (the file as the text names it). The git SHA stays in the JSON (and on the
    dashboard): this text is committed, a SHA in it would go stale."""
    prov = provenance_fields(csv_path)
    if prov is None:
        return f"Command: unknown (no {csv_path.stem}.provenance.json beside {where})."
    return f"Command: `{prov['command']}` ({prov['date']}, {prov['machine']}; {where})."
