"""Adding a bench is one module and one registry line: a tiny bench declared here (its config, its measure, one
table and one figure declared as data) is registered as a bench module's line in ``bench/registry.py`` registers
it (a new entry of ``registry.BENCHES``, patched here instead of edited), and ``bench report`` then shows its table
and its figure in the dashboard and in the README's results, with no other change."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from bench import registry, report
from bench.report_md import BEGIN, END
from bench.runner import Bench, Block, Section, execute
from gicore.present.declarations import Chart, Column, Figure, Table, pick
from gicore.results import Results, read_rows


@dataclass(frozen=True)
class TinyConfig:
    """A bench that counts."""

    #: How many counts to record.
    n: int = 3

    @classmethod
    def quick(cls) -> TinyConfig:
        return cls(n=2)


def tiny_measure(cfg: TinyConfig, res: Results) -> None:
    for i in range(cfg.n):
        res.add(system="tiny", scene="nowhere", metric="count", value=float(i * i), unit="1", index=i)


#: The tiny bench's module, in full: what it measures, its one table and its one figure, and its record.
TINY = Bench(
    "tiny",
    TinyConfig,
    tiny_measure,
    help="Counts, for the extension test.",
    dashboard=Section("tiny", "Tiny: counts", 5),
    readme=Block("Tiny counts", 5),
    parts=(
        Table(pick("count"), (Column("index", "tiny-{index}"), Column("count", "{value:g}")), title="Tiny counts"),
        Figure("tiny_counts", (Chart(pick("count"), "index", series="{system} counts", ylabel="count"),)),
    ),
    needs=("count",),
)


@pytest.fixture
def registered(monkeypatch: pytest.MonkeyPatch) -> None:
    """The one registry line: ``tiny.BENCH`` added to ``BENCHES``."""
    monkeypatch.setattr(registry, "BENCHES", (*registry.BENCHES, TINY))


def test_a_registered_bench_shows_its_table_and_figure_in_the_dashboard_and_the_readme(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, registered: None
) -> None:
    results = tmp_path / "results"
    written = execute(TINY, TinyConfig(), results / "tiny")
    assert {p.name for p in written} >= {"tiny.csv", "tiny.md", "tiny_counts.png", "tiny_counts.svg"}
    readme = tmp_path / "README.md"
    readme.write_text(f"# Project\n\n{BEGIN}\n{END}\n")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    config = report.ReportConfig(results=results, readme=readme, figures=tmp_path / "figures")
    execute(report.BENCH, config, tmp_path / "out")

    page = (tmp_path / "out" / "report.html").read_text()
    section = re.search(r'<section id="tiny"[^>]*>.*?</section>', page, re.DOTALL)
    assert section is not None and 'data-status="ok"' in section.group(0) and 'data-bench="tiny"' in section.group(0)
    html = section.group(0)
    assert "<h2>Tiny: counts</h2>" in html and "<h3>Tiny counts</h3>" in html  # the table's title below the section's
    assert "<td>tiny-2</td>" in html and "<td>4</td>" in html
    # the figure: one SVG whose three points carry their tooltips, and the declared series in its legend
    svg = re.search(r"<svg.*?</svg>", html, re.DOTALL)
    assert svg is not None and svg.group(0).count('class="pt"') == 3 and ">tiny counts</text>" in svg.group(0)
    assert page.index('<section id="tiny"') < page.index('<section id="table1"')  # order 5: before Table 1 (10)
    assert '<a class="ok" href="#tiny">Tiny: ok</a>' in page
    row = next(r for r in read_rows(tmp_path / "out" / "report.csv") if r["config"]["section"] == "tiny")
    assert (row["stat"], row["value"], row["config"]["bench"]) == ("ok", 3.0, "tiny")

    text = readme.read_text()
    block = text.split("### Tiny counts\n\n", 1)[1].split("\n### ", 1)[0]
    table = "| index | count |\n|---|---|\n| tiny-0 | 0 |\n| tiny-1 | 1 |\n| tiny-2 | 4 |"
    assert block.startswith("#### Tiny counts\n\n" + table)
    *_, command, figure = block.strip().split("\n\n")  # the table, the command that made the CSV, the figure
    assert command.startswith("Command: `") and "`tiny/tiny.csv`" in command
    assert figure == "![tiny_counts](figures/tiny/tiny_counts.png)"
    assert (tmp_path / "figures" / "tiny" / "tiny_counts.png").read_bytes().startswith(b"\x89PNG")
    assert text.index("### Tiny counts") < text.index("### Interaction latency, Table 1")


def test_a_registered_bench_whose_csv_is_missing_is_named_in_both_outputs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "results").mkdir()
    (tmp_path / "out").mkdir()
    monkeypatch.setattr(registry, "BENCHES", (TINY,))
    monkeypatch.setattr(registry, "EXTERNALS", ())
    monkeypatch.chdir(tmp_path)
    execute(report.BENCH, report.ReportConfig(results=Path("results")), tmp_path / "out")
    page = (tmp_path / "out" / "report.html").read_text()
    assert page.count("<section ") == 1 and "missing: no tiny.csv under" in page and "bench tiny --out" in page
    md = (tmp_path / "out" / "results.md").read_text()
    assert "Not in these results: missing: no tiny.csv under results; `bench tiny --out results` makes it." in md


def test_another_benchs_csv_is_malformed_for_it_not_a_crash(tmp_path: Path, registered: None) -> None:
    results = tmp_path / "results"
    (results / "tiny").mkdir(parents=True)
    res = Results("tiny", results / "tiny")
    res.add(system="x", scene="y", metric="other", value=1.0, unit="1")
    res.write()
    rendered = report.render(TINY, TINY.dashboard, results)
    assert rendered.status == "malformed" and "it has no count rows" in rendered.problem
