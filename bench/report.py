"""`bench report`: a static HTML dashboard built only from the CSV files (and provenance JSON) under a
results folder (docs/architecture.md, Report).

The dashboard has one section per registered bench that declares one (``Bench.dashboard``, in
:mod:`bench.registry`), placed by the section's ``order``: Table 1 (``latency``), Table 2 (``storage``),
Table 3 (``frequency``), Fig. 6 (``quality``), Fig. 7 (``warp``), Fig. 9 (``fov``), the Pareto fronts of
error against run time (``pareto``; hovering a point shows its full config) and the stability table
(``stability``). Each section reads its bench's ``<bench>.csv`` (found anywhere under ``--results``
outside the ``--ignore`` folders; the newest run's when there are several, :func:`bench.runner.attempt`)
and the ``<bench>.provenance.json`` beside it, and shows the parts the bench declares for the dashboard,
drawn from those rows alone (:mod:`gicore.present.html`: tables as HTML, figures as the SVG matplotlib draws,
each mark with its tooltip). Each section names its provenance: command, git SHA, machine, date. This module
only lays out the page; what a section holds is its bench's.

A section whose CSV is missing, or malformed (wrong columns, unparsable values, or rows its bench never
writes), says so and names the file; the others still render. The page is one self-contained file
(``report.html``: style sheet and script from ``bench/report_assets`` inlined, no network access), so it
opens offline. The run's own CSV (``report.csv``) has one row per section: the rows read, and the
section's status (``ok`` / ``missing`` / ``malformed``) as ``stat``.

From the same CSVs it also writes ``results.md``, the README's results section (:mod:`bench.report_md`),
and with ``--readme FILE`` puts that between the file's ``<!-- results:begin -->`` and
``<!-- results:end -->`` lines.
"""

from __future__ import annotations

import html
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench import registry
from bench.report_md import check_readme, results_markdown, update_readme
from bench.runner import Bench, External, Section, attempt, need
from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes
from gicore.present.declarations import Rows, shown
from gicore.present.html import parts_html
from gicore.results import Results, provenance_fields

ASSETS = Path(__file__).parent / "report_assets"


@dataclass(frozen=True)
class ReportConfig:
    """Where the bench outputs are."""

    #: Folder of bench outputs (searched recursively for <bench>.csv and <bench>.provenance.json).
    results: Path = Path("results")
    #: Folders under --results to leave out (relative to it; glob patterns allowed), e.g. a side run such as
    #: latency_nopin, or the frequency runs bench pareto makes in pareto/pareto_runs.
    ignore: tuple[str, ...] = field(default=(), metadata={"min_len": 0})
    #: Markdown file (e.g. README.md) whose text between the lines <!-- results:begin --> and
    #: <!-- results:end --> becomes results.md; none: no file is changed.
    readme: Path | None = None
    #: Folder to copy each block's PNG figures into, linked from the --readme file (e.g. --readme
    #: docs/results.md --figures docs/figures); none: the Markdown holds the tables only.
    figures: Path | None = None

    @classmethod
    def quick(cls) -> ReportConfig:
        return cls()

    def check(self) -> None:
        if not self.results.is_dir():
            raise UserError(
                f"--results {self.results} is not a folder", "give the folder your bench runs wrote into (their --out)"
            )
        check_readme(self.readme)
        if self.figures is not None and self.readme is None:
            raise UserError(
                "--figures needs --readme",
                "name the Markdown file that links the figures, e.g. --readme docs/results.md",
            )


def sections() -> list[tuple[Bench | External, Section]]:
    """(bench, section) of every registered bench with a dashboard section, in the sections' order."""
    with_section = [(s, s.dashboard) for s in registry.reported() if s.dashboard is not None]
    return sorted(with_section, key=lambda pair: pair[1].order)


def drawing(bench: Bench | External) -> Callable[[Rows, Path], str]:
    """How a section's HTML is made from its CSV's rows and folder: the bench's dashboard parts."""

    def draw(rows: Rows, folder: Path) -> str:
        need(rows, *bench.needs)
        return parts_html(shown(bench.parts, "dashboard"), rows, folder)

    return draw


# -- HTML of a section's parts -------------------------------------------------------------------------------
def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def provenance_html(csv_path: Path, results: Path) -> str:
    prov = provenance_fields(csv_path)
    shown = _e(csv_path.relative_to(results))
    if prov is None:
        missing = f"missing ({_e(csv_path.stem)}.provenance.json)"
        return f'<dl class="prov"><dt>file</dt><dd><code>{shown}</code></dd><dt>provenance</dt><dd>{missing}</dd></dl>'
    items = [
        ("file", f"<code>{shown}</code>"),
        ("command", f"<code>{_e(prov['command'])}</code>"),
        ("git", f"<code>{_e(prov['git'])}</code>"),
        ("machine", _e(prov["machine"])),
        ("date", _e(prov["date"])),
        ("run", f"<code>{_e(prov['run'])}</code>, seed {_e(prov['seed'])}"),
    ]
    return '<dl class="prov">' + "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in items) + "</dl>"


# -- the page --------------------------------------------------------------------------------------------------
@dataclass
class Rendered:
    """One section as drawn: status ``ok`` / ``missing`` / ``malformed``, its HTML, what it read."""

    bench: str
    section: Section
    status: str
    body: str
    file: str = ""
    rows: int = 0
    problem: str = ""
    others: list[str] = field(default_factory=list)


def render(shown_bench: Bench | External, section: Section, results: Path, ignore: tuple[str, ...] = ()) -> Rendered:
    """The section of ``bench``'s newest CSV under ``results``, or one naming what is missing or malformed."""
    bench = shown_bench.name
    a = attempt(bench, results, drawing(shown_bench), ignore)
    if a.path is None:
        todo = f"run <code>bench {bench} --out {_e(results)}</code> (or into a folder under it)"
        return Rendered(
            bench, section, "missing", f'<p class="problem">{_e(a.problem)}; {todo}.</p>', problem=a.problem
        )
    prov = provenance_html(a.path, results)
    if a.status != "ok":
        problem = f'<p class="problem">{_e(a.problem)}</p>'
        return Rendered(bench, section, a.status, prov + problem, a.rel, problem=a.problem, others=a.others)
    note = f"<p>Newest of {len(a.others) + 1} runs; older: {_e(', '.join(a.others))}.</p>" if a.others else ""
    return Rendered(bench, section, "ok", prov + note + a.parts, a.rel, a.rows, others=a.others)


def page(parts: list[Rendered], results: Path) -> str:
    css = (ASSETS / "report.css").read_text()
    js = (ASSETS / "report.js").read_text()
    nav = "".join(
        f'<a class="{p.status}" href="#{p.section.key}">{_e(p.section.title.split(":")[0])}: {p.status}</a>'
        for p in parts
    )
    sections = "".join(
        f'<section id="{p.section.key}" data-status="{p.status}" data-bench="{p.bench}">'
        f"<h2>{_e(p.section.title)}</h2>{p.body}</section>"
        for p in parts
    )
    made = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>GIGAN testbed results</title><style>{css}</style></head><body>"
        f"<header><h1>GIGAN testbed: results dashboard</h1><p>Built {made} from the CSV files under "
        f"<code>{_e(results)}</code> (bench report). Hover a chart mark for its values; Pareto points show their "
        "full config.</p></header>"
        f'<nav>{nav}</nav><main>{sections}</main><div id="tip" hidden></div><script>{js}</script></body></html>\n'
    )


def measure(cfg: ReportConfig, res: Results) -> None:
    results = cfg.results.resolve()
    parts = [render(bench, section, results, cfg.ignore) for bench, section in sections()]
    atomic_write_bytes(res.output("report.html"), page(parts, results).encode())
    text = results_markdown(cfg.results, cfg.ignore, cfg.figures, cfg.readme)
    atomic_write_bytes(res.output("results.md"), text.encode())
    if cfg.readme is not None:
        update_readme(cfg.readme, text)
        res.files.append(cfg.readme)
    for p in parts:
        config = {
            "section": p.section.key,
            "bench": p.bench,
            "file": p.file,
            "problem": p.problem,
            "older_runs": p.others,
        }
        res.add(system="report", scene="all", metric="section_rows", value=p.rows, unit="rows", stat=p.status, **config)


BENCH = Bench(
    "report",
    ReportConfig,
    measure,
    help="A static HTML dashboard (report.html, opens offline) from the CSV files and provenance under --results: "
    "Tables 1-3, Fig. 6, 7, 9, the Pareto fronts (hover a point for its config), the stability table; a missing or "
    "malformed CSV is named in its section. Also results.md, the README's results section (each block with the "
    "command that made it); --readme puts it between the file's markers.",
)
