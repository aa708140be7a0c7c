"""The dashboard's HTML: a bench's parts (tables, their cells and captions Markdown rendered inline; figures as
the inline SVG :mod:`gicore.present.charts` draws; images as data URIs; alerts), a results CSV's provenance, and
the page that holds the sections, one self-contained file (style sheet and script from ``assets/`` inlined), so
that it opens offline."""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from gicore.present import charts
from gicore.present.declarations import Alert, Figure, Image, Part, Rows, Table, fill, text
from gicore.present.markdown import columns, groups
from gicore.results import provenance_fields

ASSETS = Path(__file__).parent / "assets"


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


def provenance_html(csv_path: Path, results: Path) -> str:
    """Where a results CSV came from, as a definition list: the file (relative to ``results``), and from the
    provenance JSON beside it the command, git SHA, machine, date, run and seed (or that it is missing)."""
    prov = provenance_fields(csv_path)
    shown = e(csv_path.relative_to(results))
    if prov is None:
        missing = f"missing ({e(csv_path.stem)}.provenance.json)"
        return f'<dl class="prov"><dt>file</dt><dd><code>{shown}</code></dd><dt>provenance</dt><dd>{missing}</dd></dl>'
    items = [
        ("file", f"<code>{shown}</code>"),
        ("command", f"<code>{e(prov['command'])}</code>"),
        ("git", f"<code>{e(prov['git'])}</code>"),
        ("machine", e(prov["machine"])),
        ("date", e(prov["date"])),
        ("run", f"<code>{e(prov['run'])}</code>, seed {e(prov['seed'])}"),
    ]
    return '<dl class="prov">' + "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in items) + "</dl>"


@dataclass(frozen=True)
class PageSection:
    """One section of the page: its anchor, heading (the part before a colon names it in the navigation),
    status (``ok``, or what went wrong, e.g. ``missing``), the name of what it shows, and its HTML."""

    key: str
    title: str
    status: str
    name: str
    body: str


def page(sections: Sequence[PageSection], title: str, header: str) -> str:
    """The page: ``header`` (HTML) over a navigation bar that names each section with its status, then the
    sections; a chart mark's tooltip shows on hover."""
    css = (ASSETS / "report.css").read_text()
    js = (ASSETS / "report.js").read_text()
    nav = "".join(f'<a class="{s.status}" href="#{s.key}">{e(s.title.split(":")[0])}: {s.status}</a>' for s in sections)
    body = "".join(
        f'<section id="{s.key}" data-status="{s.status}" data-bench="{s.name}"><h2>{e(s.title)}</h2>{s.body}</section>'
        for s in sections
    )
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{e(title)}</title><style>{css}</style></head><body><header>{header}</header>"
        f'<nav>{nav}</nav><main>{body}</main><div id="tip" hidden></div><script>{js}</script></body></html>\n'
    )
