"""Tables as Markdown: the README's results blocks and each bench's ``<bench>.md``."""

from __future__ import annotations

from collections.abc import Iterable

from gicore.present.declarations import Column, Part, Rows, Table, fill, text, unique


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
