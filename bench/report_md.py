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
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bench import registry
from bench.present.declarations import Rows, shown
from bench.present.markdown import tables_text
from bench.runner import Attempt, Bench, Block, External, Part, Table, attempt, need, provenance_fields
from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes

BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


def blocks() -> list[tuple[str, Block]]:
    """(bench, block) of every registered bench with a README block, in the blocks' order."""
    return [(b.name, block) for b, block in shown_blocks()]


def shown_blocks() -> list[tuple[Bench | External, Block]]:
    with_block = [(s, s.readme) for s in registry.SHOWN if s.readme is not None]
    return sorted(with_block, key=lambda pair: pair[1].order)


def writing(bench: Bench | External, block: Block) -> Callable[[Rows, Path], str]:
    """How a block's Markdown is made from its CSV's rows: the bench's README tables."""
    if block.write is not None:
        old = block.write
        return lambda rows, _: block_text(old(rows))

    def write(rows: Rows, _: Path) -> str:
        need(rows, *bench.needs)
        return tables_text(shown(bench.parts, "readme"), rows, 4)

    return write


def make_command(bench: str, block: Block, results: Path) -> str:
    """The command that makes ``bench``'s CSV under ``results`` (named when it is missing)."""
    return (block.make or f"bench {bench} --out {{out}}").format(out=results)


def _demote(text: str, top: int = 4) -> str:
    """A bench's Markdown with its headings moved down so that the highest is level ``top`` (below the
    block's own ``###``)."""
    levels = [len(m.group(1)) for m in re.finditer(r"^(#+) ", text, re.MULTILINE)]
    shift = max(0, top - min(levels)) if levels else 0
    return re.sub(r"^(#+) ", lambda m: "#" * (len(m.group(1)) + shift) + " ", text, flags=re.MULTILINE)


def block_text(parts: Sequence[Part]) -> str:
    """A block's tables as Markdown (figures and alerts are the dashboard's)."""
    return "\n\n".join(_demote(p.markdown).strip() for p in parts if isinstance(p, Table))


def command_line(a: Attempt) -> str:
    """Where a block's numbers come from: the command, date and machine of its CSV. The git SHA stays in the
    provenance JSON beside the CSV (and on the dashboard): this text is committed, a SHA in it would go stale."""
    assert a.path is not None
    where = f"`{a.rel}`" + (f", the newest of {len(a.others) + 1} runs" if a.others else "")
    prov = provenance_fields(a.path)
    if prov is None:
        return f"Command: unknown (no {a.path.stem}.provenance.json beside {where})."
    return f"Command: `{prov['command']}` ({prov['date']}, {prov['machine']}; {where})."


def figure_links(a: Attempt, figures: Path, page: Path) -> str:
    """Copy the PNG figures the bench drew beside its CSV (``<bench>*.png``) into ``figures/<bench>/`` and link
    them as Markdown images relative to ``page``, the file the text goes into; empty when it drew none."""
    assert a.path is not None
    links = []
    for png in sorted(a.path.parent.glob(f"{a.path.stem}*.png")):
        target = figures / a.path.stem / png.name
        target.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(target, png.read_bytes())
        links.append(f"![{png.stem}]({Path(os.path.relpath(target, page.parent)).as_posix()})")
    return "\n".join(links)


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
        a = attempt(bench, results, writing(shown_bench, block), ignore)
        parts.append(f"### {block.title}")
        if a.status == "missing":
            parts.append(f"Not in these results: {a.problem}; `{make_command(bench, block, results)}` makes it.")
        elif a.status == "malformed":
            parts.append(f"Not shown: {a.problem}.")
        else:
            parts += [a.parts, command_line(a)]
            images = figure_links(a, figures, page) if figures is not None and page is not None else ""
            parts += [images] if images else []
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
