"""A bench's parts as the dashboard's HTML: tables (cells and captions are Markdown, rendered inline), figures
as the inline SVG :mod:`gicore.present.charts` draws, images as data URIs (the page opens offline), alerts."""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable
from functools import cache
from pathlib import Path
from typing import Any

from gicore.present import charts
from gicore.present.declarations import Alert, Figure, Image, Part, Rows, Table, fill, text
from gicore.present.markdown import columns, groups


def e(value: Any) -> str:
    return html.escape(str(value), quote=True)


@cache
def _md() -> Any:
    from markdown_it import MarkdownIt

    return MarkdownIt("commonmark", {"html": False}).enable("table")


def prose(markdown: str) -> str:
    """Markdown paragraphs as HTML."""
    return _md().render(markdown) if markdown else ""


def inline(markdown: str) -> str:
    return _md().renderInline(markdown)


def table_html(table: Table, rows: Rows) -> str:
    derived = table.rows(rows)
    if not derived:
        return ""
    cols = columns(table, rows)
    title = text(table.title, rows)
    out = [f"<h3>{inline(title)}</h3>"] if title else []
    out.append(prose(text(table.caption, rows)))
    for heading, mine in groups(table, derived):
        out += [f"<h4>{inline(heading)}</h4>"] if heading else []
        head = "".join(f"<th>{inline(c.header)}</th>" for c in cols)
        body = "".join("<tr>" + "".join(f"<td>{inline(fill(c.cell, r))}</td>" for c in cols) + "</tr>" for r in mine)
        out.append(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")
        out.append(prose(fill(table.group_note, mine[0])) if table.group_note else "")
    out.append(prose(text(table.notes, rows)))
    inner = f'<div class="md">{"".join(out)}</div>'
    return f'<div class="scroll">{inner}</div>' if table.scroll else inner


def figure_html(figure: Figure, rows: Rows) -> str:
    svg = charts.render(figure, rows)
    caption = text(figure.caption, rows)
    return f'<figure class="charts">{svg}<figcaption>{inline(caption)}</figcaption></figure>' if svg else ""


def image_html(image: Image, folder: Path) -> str:
    path = folder / image.file
    if not path.is_file():
        return f"<p>(no {e(image.file)} beside the CSV)</p>"
    data = base64.b64encode(path.read_bytes()).decode()
    caption = f"<figcaption>{inline(image.caption)}</figcaption>" if image.caption else ""
    return f'<figure><img alt="{e(image.file)}" src="data:image/png;base64,{data}">{caption}</figure>'


def parts_html(parts: Iterable[Part], rows: Rows, folder: Path) -> str:
    """The parts as HTML, in order."""
    out = []
    for part in parts:
        match part:
            case Table():
                out.append(table_html(part, rows))
            case Figure():
                out.append(figure_html(part, rows))
            case Image():
                out.append(image_html(part, folder))
            case Alert():
                line = part.text(rows)
                out.append(f'<p class="problem">{e(line)}</p>' if line else "")
    return "".join(out)
