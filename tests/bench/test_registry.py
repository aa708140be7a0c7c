"""The bench registry: a bench declares what ``bench report`` shows of its CSV, and one registration line puts
it in the dashboard and in the README's results section; nothing in the report names a bench."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from bench import cli, registry, report
from bench.report_md import BEGIN, END
from bench.runner import Bench, Block, Figure, Part, Rows, Section, Table, execute, need, pick
from bench.svg import BarChart
from gicore.results import Results, read_rows


@dataclass(frozen=True)
class ToyConfig:
    """A bench that counts."""

    #: How many counts to record.
    n: int = 3

    @classmethod
    def quick(cls) -> ToyConfig:
        return cls(n=2)


def toy_measure(cfg: ToyConfig, res: Results) -> None:
    for i in range(cfg.n):
        res.add(system="toy", scene="nowhere", metric="count", value=float(i * i), unit="1", stat="value", index=i)


def toy_tables(rows: Rows) -> list[Table]:
    need(rows, "count")
    lines = ["| index | count |", "|---|---|"]
    lines += [f"| toy-{r['config']['index']} | {r['value']:g} |" for r in pick(rows, "count")]
    return [Table("### Toy counts\n\n" + "\n".join(lines))]


def toy_section(rows: Rows) -> list[Part]:
    chart = BarChart([f"toy-{r['config']['index']}" for r in rows], {"count": [r["value"] for r in rows]}, "count")
    return [*toy_tables(rows), Figure((chart,))]


TOY = Bench(
    "toy",
    ToyConfig,
    toy_measure,
    None,
    help="Counts, for the registry's test.",
    dashboard=Section("toy", "Toy: counts", 5, toy_section),
    readme=Block("Toy counts", 5, toy_tables),
)


def test_a_registered_toy_bench_shows_its_table_in_the_dashboard_and_the_readme(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    results = tmp_path / "results"
    execute(TOY, ToyConfig(), results / "toy")
    monkeypatch.setattr(registry, "SHOWN", (*registry.SHOWN, TOY))  # the one registration line
    readme = tmp_path / "README.md"
    readme.write_text(f"# Project\n\n{BEGIN}\n{END}\n")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    execute(report.BENCH, report.ReportConfig(results=results, readme=readme), tmp_path / "out")

    page = (tmp_path / "out" / "report.html").read_text()
    section = re.search(r'<section id="toy"[^>]*>.*?</section>', page, re.DOTALL)
    assert section is not None and 'data-status="ok"' in section.group(0) and 'data-bench="toy"' in section.group(0)
    html = section.group(0)
    assert "<h2>Toy: counts</h2>" in html and "<h5>Toy counts</h5>" in html  # the table's heading below the section's
    assert "<td>toy-2</td>" in html and "<td>4</td>" in html and html.count('<rect class="pt"') == 3
    assert page.index('<section id="toy"') < page.index('<section id="table1"')  # order 5: before Table 1 (10)
    assert '<a class="ok" href="#toy">Toy: ok</a>' in page
    row = next(r for r in read_rows(tmp_path / "out" / "report.csv") if r["config"]["section"] == "toy")
    assert (row["stat"], row["value"], row["config"]["bench"]) == ("ok", 3.0, "toy")

    text = readme.read_text()
    block = text.split("### Toy counts\n\n", 1)[1].split("\n### ", 1)[0]
    table = "| index | count |\n|---|---|\n| toy-0 | 0 |\n| toy-1 | 1 |\n| toy-2 | 4 |"
    assert block.startswith("#### Toy counts\n\n" + table)
    assert block.splitlines()[-1].startswith("Command: `") and "`toy/toy.csv`" in block
    assert text.index("### Toy counts") < text.index("### Interaction latency, Table 1")


def test_a_registered_bench_whose_csv_is_missing_is_named_in_both_outputs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "results").mkdir()
    (tmp_path / "out").mkdir()
    monkeypatch.setattr(registry, "SHOWN", (TOY,))
    monkeypatch.chdir(tmp_path)
    execute(report.BENCH, report.ReportConfig(results=Path("results")), tmp_path / "out")
    page = (tmp_path / "out" / "report.html").read_text()
    assert page.count("<section ") == 1 and "missing: no toy.csv under" in page and "bench toy --out" in page
    md = (tmp_path / "out" / "results.md").read_text()
    assert "Not in these results: missing: no toy.csv under results; `bench toy --out results` makes it." in md


def test_every_bench_is_registered_once_and_each_place_in_the_report_is_its_own() -> None:
    names = [b.name for b in cli.BENCHES]
    assert names[-1] == "report" and len(set(names)) == len(names)
    assert cli.BENCHES == (*registry.BENCHES, report.BENCH)
    sections = [s.dashboard for s in registry.SHOWN if s.dashboard is not None]
    blocks = [s.readme for s in registry.SHOWN if s.readme is not None]
    for places in (sections, blocks):
        assert len({p.order for p in places}) == len(places) and len({p.title for p in places}) == len(places)
    assert len({s.key for s in sections}) == len(sections)
