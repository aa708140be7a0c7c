"""`bench report`: the dashboard from CSV files only, checked as HTML and in a real browser (Chromium via Playwright).

The results folder is ``tests/bench/fixtures/report_results``: small real outputs of ``bench latency``, ``storage``,
``frequency``, ``quality``, ``warp``, ``fov``, ``pareto``, ``stability``, ``convergence``, ``service``, ``scaling`` and
``network-sim selftest`` (the commands are in each provenance JSON); the report of all of it is built once per test
run (tests/bench/report_fixtures.py), the others from copies changed per test.
The browser is Debian's ``chromium`` (``scripts/setup.sh`` installs it when root); without it the browser tests
skip, except under ``CI=true``, where a missing browser fails. The dashboard's screenshot goes into the test's
temporary folder.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

from gicore.results import read_rows
from tests.bench.report_fixtures import FIXTURES, report_of_everything, spoil_value
from tests.helpers.cli import exit_status

CHROMIUM = Path("/usr/bin/chromium")
SECTIONS = ("table1", "table2", "table3", "fig6", "fig7", "fig9", "pareto", "stability", "web", "prefetch", "variants")
#: Rows and points a section draws at least: three, but bench variants has a row per device (two in its fixture).
MIN_DRAWN = {"variants": 2}


def build(results: Path, out: Path) -> tuple[Path, dict[str, dict]]:
    """Run ``bench report`` (its main, in this process); the HTML and each section's row of report.csv."""
    assert exit_status(["bench", "report", "--results", str(results), "--out", str(out)]) == 0
    return drawn(out)


def drawn(out: Path) -> tuple[Path, dict[str, dict]]:
    return out / "report.html", {r["config"]["section"]: r for r in read_rows(out / "report.csv")}


@pytest.fixture(scope="module")
def complete(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, dict]]:
    return drawn(report_of_everything(tmp_path_factory) / "one")


@pytest.fixture(scope="module")
def broken(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, dict]]:
    """The fixtures without pareto.csv and with a warp.csv whose values do not parse."""
    results = tmp_path_factory.mktemp("broken")
    shutil.copytree(FIXTURES, results, dirs_exist_ok=True)
    (results / "pareto" / "pareto.csv").unlink()
    spoil_value(results / "warp" / "warp.csv")
    return build(results, tmp_path_factory.mktemp("report"))


@pytest.mark.slow
def test_every_section_renders_from_the_fixture_csvs(complete) -> None:
    html, sections = complete
    assert set(sections) == set(SECTIONS)
    for key, row in sections.items():
        assert row["stat"] == "ok" and row["value"] > 0, (key, row["config"]["problem"])
    text = html.read_text()
    # self-contained: no external script, style sheet, image or font
    assert (
        not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text) and "<link" not in text and "@import" not in text
    )
    for command in ("bench latency", "bench storage", "bench pareto --quick", "bench stability --quick"):
        assert command in text  # each section's provenance names the command that made its CSV
    assert text.count('class="prov"') == len(SECTIONS)


def test_missing_and_malformed_csvs_are_named_and_the_rest_renders(broken) -> None:
    html, sections = broken
    assert sections["pareto"]["stat"] == "missing" and "no pareto.csv" in sections["pareto"]["config"]["problem"]
    fig7 = sections["fig7"]
    assert fig7["stat"] == "malformed" and fig7["config"]["problem"].startswith(
        "malformed: warp/warp.csv: a row does not parse"
    )
    assert all(sections[k]["stat"] == "ok" for k in SECTIONS if k not in ("pareto", "fig7"))
    text = html.read_text()
    assert "missing: no pareto.csv under" in text and "malformed: warp/warp.csv" in text


def test_a_csv_of_another_shape_is_malformed_not_a_crash(tmp_path: Path) -> None:
    results = tmp_path / "results"
    shutil.copytree(FIXTURES / "quality", results / "quality")
    shutil.copy(FIXTURES / "warp" / "warp.csv", results / "quality" / "quality.csv")  # tidy, but not quality's rows
    (results / "fov").mkdir()
    (results / "fov" / "fov.csv").write_text("a,b\n1,2\n")
    _, sections = build(results, tmp_path / "out")
    assert sections["fig6"]["stat"] == "malformed" and "no rmse, psnr rows" in sections["fig6"]["config"]["problem"]
    assert (
        sections["fig9"]["stat"] == "malformed"
        and "its columns are ['a', 'b']" in sections["fig9"]["config"]["problem"]
    )


def test_a_missing_results_folder_is_one_error_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert exit_status(["bench", "report", "--results", str(tmp_path / "nope"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "--results" in errors[0] and "Traceback" not in err


# -- in a real browser ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.is_file():
        reason = f"{CHROMIUM} is missing: install it with 'apt-get install chromium' (scripts/setup.sh does when root)"
        if os.environ.get("CI") == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is missing: pip install -e '.[test]'")
    args = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--no-first-run",
    ]
    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=str(CHROMIUM), args=args)
        yield chromium
        chromium.close()


def open_page(browser, html: Path):
    """The report in a new page, with every console error and page error collected in ``page.errors``."""
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    errors: list[str] = []
    page.on(
        "console", lambda m: errors.append(f"console {m.type}: {m.text}") if m.type in ("error", "warning") else None
    )
    page.on("pageerror", lambda e: errors.append(f"page error: {e}"))
    page.on("requestfailed", lambda r: errors.append(f"request failed: {r.url}"))
    page.errors = errors
    page.goto(html.as_uri(), wait_until="load")
    return page


def test_dashboard_in_chromium_every_section_has_data_and_a_pareto_point_shows_its_config(
    browser, complete, tmp_path: Path
) -> None:
    html, _ = complete
    page = open_page(browser, html)
    for key in SECTIONS:
        section = page.locator(f"section#{key}")
        assert section.get_attribute("data-status") == "ok", key
        assert section.locator("dl.prov dd").first.is_visible()
        drawn = section.locator("table tbody tr").count() + section.locator("svg .pt").count()
        assert drawn >= MIN_DRAWN.get(key, 3), (key, drawn)
    assert page.locator("section#fig6 svg .pt").count() >= 4 and page.locator("section#table3 svg .pt").count() >= 6
    tip = page.locator("#tip")
    assert tip.is_hidden()
    point = page.locator("section#pareto svg .pt").first
    point.scroll_into_view_if_needed()
    point.hover()
    tip.wait_for(state="visible", timeout=30_000)
    text = tip.inner_text()
    assert re.search(r"^(gigan|cloud_baking) \(lung_plane\), (dominated|on the front)", text), text
    assert '"knob":' in text and '"per":' in text and "run time" in text and "error (1-SSIM)" in text
    page.mouse.move(2, 2)
    tip.wait_for(state="hidden", timeout=30_000)
    shot = tmp_path / "report_dashboard.png"  # the test writes nothing into the working tree
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 10_000
    assert page.errors == []


def test_dashboard_in_chromium_says_what_is_missing(browser, broken) -> None:
    html, _ = broken
    page = open_page(browser, html)
    assert page.locator("section#pareto").get_attribute("data-status") == "missing"
    assert "missing: no pareto.csv" in page.locator("section#pareto .problem").inner_text()
    assert "malformed: warp/warp.csv" in page.locator("section#fig7 .problem").inner_text()
    assert page.locator("section#table1 table tbody tr").count() > 10  # the others still render
    assert page.locator("nav a.missing").inner_text().startswith("Error against run time")
    assert page.errors == []


def test_the_newest_of_several_runs_is_shown_and_the_older_named(tmp_path: Path) -> None:
    results = tmp_path / "results"
    for name, finished in (("old", 1.0e9), ("new", 2.0e9)):
        folder = results / name
        shutil.copytree(FIXTURES / "warp", folder)
        provenance = folder / "warp.provenance.json"
        provenance.write_text(
            provenance.read_text().replace('"finished_unix":', f'"finished_unix": {finished}, "was":', 1)
        )
    html, sections = build(results, tmp_path / "out")
    assert sections["fig7"]["config"]["file"] == "new/warp.csv" and sections["fig7"]["config"]["older_runs"] == [
        "old/warp.csv"
    ]
    assert "Newest of 2 runs; older: old/warp.csv." in html.read_text()
