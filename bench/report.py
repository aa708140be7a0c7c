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
only picks and orders the sections; the page's HTML is :mod:`gicore.present.html`'s, what a section holds is
its bench's.

A section whose CSV is missing, or malformed (wrong columns, unparsable values, or rows its bench never
writes), says so and names the file; the others still render. The page is one self-contained file
(``report.html``, :func:`gicore.present.html.page`: no network access), so it opens offline. The run's own CSV
(``report.csv``) has one row per section: the rows read, and the section's status (``ok`` / ``missing`` /
``malformed``) as ``stat``.

From the same CSVs it also writes ``results.md``, the README's results section (:mod:`bench.report_md`),
and with ``--readme FILE`` puts that between the file's ``<!-- results:begin -->`` and
``<!-- results:end -->`` lines.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from bench import registry
from bench.report_md import check_readme, results_markdown, update_readme
from bench.runner import Bench, External, Section, attempt, need
from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes
from gicore.present.declarations import Rows, shown
from gicore.present.html import PageSection, e, page, parts_html, provenance_html
from gicore.results import Results


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
        todo = f"run <code>bench {bench} --out {e(results)}</code> (or into a folder under it)"
        return Rendered(bench, section, "missing", f'<p class="problem">{e(a.problem)}; {todo}.</p>', problem=a.problem)
    prov = provenance_html(a.path, results)
    if a.status != "ok":
        problem = f'<p class="problem">{e(a.problem)}</p>'
        return Rendered(bench, section, a.status, prov + problem, a.rel, problem=a.problem, others=a.others)
    note = f"<p>Newest of {len(a.others) + 1} runs; older: {e(', '.join(a.others))}.</p>" if a.others else ""
    return Rendered(bench, section, "ok", prov + note + a.parts, a.rel, a.rows, others=a.others)


def dashboard(parts: list[Rendered], results: Path) -> str:
    """The page of the sections ``parts``, built now from the CSV files under ``results``."""
    made = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    header = (
        f"<h1>GIGAN testbed: results dashboard</h1><p>Built {made} from the CSV files under <code>{e(results)}</code> "
        "(bench report). Hover a chart mark for its values; Pareto points show their full config.</p>"
    )
    shown = [PageSection(p.section.key, p.section.title, p.status, p.bench, p.body) for p in parts]
    return page(shown, "GIGAN testbed results", header)


def measure(cfg: ReportConfig, res: Results) -> None:
    results = cfg.results.resolve()
    parts = [render(bench, section, results, cfg.ignore) for bench, section in sections()]
    atomic_write_bytes(res.output("report.html"), dashboard(parts, results).encode())
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
