"""The README's results section, in Markdown, from the same CSV files and provenance as the dashboard.

``bench report`` writes it as ``results.md`` beside ``report.html`` and, with ``--readme FILE``, puts it
between the lines ``<!-- results:begin -->`` and ``<!-- results:end -->`` of that file (everything between
them is replaced; everything outside them, such as what the numbers mean for choosing a system, is left
alone; a second run with the same results changes nothing).

There is one block per registered bench that declares one (``readme`` of its ``Bench``, or of an
:class:`bench.runner.External` for a CSV another program writes, in :mod:`bench.registry`), placed by the
block's ``order``: Table 1, Table 2, error against run time, Table 3, Fig. 6, 7, 9, the cloud-baking
server, the network simulator's self-test, numerical stability and scaling. Each block reads its bench's
newest CSV under ``--results`` (outside the ``--ignore`` folders) through :func:`bench.runner.attempt`
(the dashboard's finder, loader and checks), shows the tables the bench writes from those rows, and ends
with the command that wrote the CSV, its git SHA, date and machine (from the provenance JSON beside it). A
block whose CSV is missing or malformed says so in one line. This module only renders; what a block says
is its bench's.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import registry
from bench.runner import Attempt, Bench, Block, External, attempt, need
from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes
from gicore.present import charts
from gicore.present.declarations import Figure, Image, Part, Rows, shown
from gicore.present.markdown import tables_text
from gicore.results import provenance_fields

BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


def blocks() -> list[tuple[str, Block]]:
    """(bench, block) of every registered bench with a README block, in the blocks' order."""
    return [(b.name, block) for b, block in shown_blocks()]


def shown_blocks() -> list[tuple[Bench | External, Block]]:
    with_block = [(s, s.readme) for s in registry.reported() if s.readme is not None]
    return sorted(with_block, key=lambda pair: pair[1].order)


def writing(bench: Bench | External, figures: Path | None, page: Path | None) -> Callable[[Rows, Path], list[str]]:
    """How a block's Markdown is made from its CSV's rows and folder: the bench's README tables, and with
    ``figures`` its figures' links (:func:`figure_links`)."""

    def write(rows: Rows, folder: Path) -> list[str]:
        need(rows, *bench.needs)
        parts = shown(bench.parts, "readme")
        links = figure_links(bench.name, parts, rows, folder, figures, page) if figures and page else ""
        return [tables_text(parts, rows, 4), links]

    return write


def make_command(bench: str, block: Block, results: Path) -> str:
    """The command that makes ``bench``'s CSV under ``results`` (named when it is missing)."""
    return (block.make or f"bench {bench} --out {{out}}").format(out=results)


def command_line(a: Attempt) -> str:
    """Where a block's numbers come from: the command, date and machine of its CSV. The git SHA stays in the
    provenance JSON beside the CSV (and on the dashboard): this text is committed, a SHA in it would go stale."""
    assert a.path is not None
    where = f"`{a.rel}`" + (f", the newest of {len(a.others) + 1} runs" if a.others else "")
    prov = provenance_fields(a.path)
    if prov is None:
        return f"Command: unknown (no {a.path.stem}.provenance.json beside {where})."
    return f"Command: `{prov['command']}` ({prov['date']}, {prov['machine']}; {where})."


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


def _shown(results: Path) -> Path:
    """``results`` relative to the working folder when it lies inside it (so the text does not name this
    machine's paths)."""
    try:
        return results.resolve().relative_to(Path.cwd().resolve())
    except ValueError:
        return results


def results_markdown(
    results: Path, ignore: tuple[str, ...] = (), figures: Path | None = None, page: Path | None = None
) -> str:
    """The results section: a heading per block, its numbers and the command that made them (or one line saying
    what is missing or malformed), and with ``figures`` each block's PNG figures, copied there and linked from
    ``page``. Nothing in it depends on when it is built, so rebuilding it from the same results gives the same
    text."""
    results = _shown(results)
    options = f"--results {results}" + (f" --ignore {','.join(ignore)}" if ignore else "")
    parts = [
        f"<!-- Generated by `bench report {options} --readme FILE` from the CSV files under {results}; "
        "edits between the results markers are replaced on the next run. -->",
        f"Generated from the CSV files under `{results}` by `bench report`; each block ends with the command that "
        "wrote its CSV.",
    ]
    for shown_bench, block in shown_blocks():
        bench = shown_bench.name
        a = attempt(bench, results, writing(shown_bench, figures, page), ignore)
        parts.append(f"### {block.title}")
        if a.status == "missing":
            parts.append(f"Not in these results: {a.problem}; `{make_command(bench, block, results)}` makes it.")
        elif a.status == "malformed":
            parts.append(f"Not shown: {a.problem}.")
        else:
            text, images = a.parts
            parts += [text, command_line(a)] + ([images] if images else [])
    return "\n\n".join(parts) + "\n"


# -- the README's markers ------------------------------------------------------------------------------------------
def marker_span(text: str, readme: Path) -> tuple[int, int]:
    """Where the generated section goes in ``text``: from the end of the begin marker to the start of the end
    marker; a :class:`UserError` unless there is exactly one of each, in that order."""
    begins, ends = text.count(BEGIN), text.count(END)
    start, stop = text.find(BEGIN), text.find(END)
    if begins != 1 or ends != 1 or stop < start:
        raise UserError(
            f"--readme {readme} has {begins} '{BEGIN}' and {ends} '{END}' lines, not one of each in that order",
            f"put the line {BEGIN} where the generated results begin and {END} where they end (the text between is "
            "replaced), then run again",
        )
    return start + len(BEGIN), stop


def read_readme(readme: Path) -> str:
    try:
        return readme.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(
            f"--readme {readme} cannot be read ({getattr(exc, 'strerror', None) or exc})",
            "give the Markdown file to update, e.g. --readme README.md",
        ) from None


def update_readme(readme: Path, section: str) -> bool:
    """Put ``section`` between the markers of ``readme``; True when the file changed (the same section twice:
    no change)."""
    text = read_readme(readme)
    start, stop = marker_span(text, readme)
    new = text[:start] + "\n\n" + section.strip("\n") + "\n\n" + text[stop:]
    if new == text:
        return False
    atomic_write_bytes(readme, new.encode("utf-8"))
    return True


def check_readme(readme: Any) -> None:
    """Refuse a ``--readme`` that cannot be read or has no markers, before the report is built."""
    if readme is not None:
        marker_span(read_readme(Path(readme)), Path(readme))
