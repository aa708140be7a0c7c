"""`bench report`'s Markdown results section (``results.md``, ``--readme``) from the fixture results.

The fixtures (``tests/bench/fixtures/report_results``) are small real outputs of the benches; their commands are
in each provenance JSON. The expected numbers below are read off those CSVs (some recomputed here from the
rows, some as the fixture holds them). The ``bench report --readme`` of all of them is the dashboard tests' run
(tests/bench/report_fixtures.py).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from bench.report_md import BEGIN, END, results_markdown, update_readme
from bench.report_md import blocks as readme_blocks
from gicore.error_policy import UserError
from gicore.results import read_rows
from tests.bench.report_fixtures import FIXTURES, report_of_everything, spoil_value
from tests.helpers.cli import exit_status


def sections(markdown: str) -> dict[str, str]:
    """Block title -> its text (up to the next block)."""
    parts = markdown.split("\n### ")[1:]
    return {part.split("\n", 1)[0]: part.split("\n", 1)[1].strip() for part in parts}


def expected_command(provenance: Path) -> str:
    """The command as the provenance recorded it: the program's name, then its arguments."""
    argv = json.loads(provenance.read_text())["argv"]
    return " ".join([Path(argv[0]).name, *argv[1:]])


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """``bench report --results results --out one --readme README.md`` run from a folder holding the fixtures as
    ``results`` (read-only): the folder, the README after the run, the run's results.md."""
    root = report_of_everything(tmp_path_factory)
    return root, root / "README.md", root / "one" / "results.md"


def test_every_block_has_its_numbers_and_the_command_that_made_them(generated) -> None:
    root, _, results_md = generated
    text = results_md.read_text()
    blocks = sections(text)
    assert list(blocks) == [block.title for _, block in readme_blocks()]
    # every fixture CSV is there: each block ends with its command, from the provenance beside the CSV
    for bench, block in readme_blocks():
        provenance = next((root / "results").rglob(f"{bench}.provenance.json"))
        last = blocks[block.title].splitlines()[-1]
        assert last.startswith(f"Command: `{expected_command(provenance)}` ("), (block.title, last)
        assert f"`{provenance.parent.name}/{bench}.csv`" in last and "2 cores" in last
    assert (
        "Command: `bench latency --quick --profiles lan,wan --frames 16 --every 4 --spp 4 --gt-every 8 "
        "--out /tmp/fx/latency` (20" in text
    )
    # the SHA stays in the provenance JSON: the Markdown is committed and would name a commit that goes stale
    assert "git " not in text and "5ca1ab1e5ca1" not in text
    assert "Command: `network-sim selftest --out results/final/netself`" in text  # not bench: the program by its name

    # Table 1: one row per profile, recomputed from the CSV's medians
    rows = read_rows(root / "results" / "latency" / "latency.csv")
    gigan = next(r["value"] for r in rows if (r["system"], r["metric"], r["stat"]) == ("gigan", "total", "median"))
    assert (
        f"| `lan` (0.5 ms) | mitsuba | {gigan:.1f} | 38.9 | 342.1 | 0.61 / 5.34 | 0.879 / 0.961 / 0.938 |"
        in blocks["Interaction latency, Table 1"]
    )
    assert "| `wan` (130 ms) | mitsuba | 64.0 | 176.9 | 687.1 | 2.76 / 10.73 |" in text  # a run before renderers
    assert "beats a cloud hit beyond an RTT of 38 ms (mitsuba); a cloud miss at any RTT (mitsuba)." in text
    # Table 2: GI tree per codec against the fp16 model
    assert (
        "fp32 10 MiB, fp16 5.01 MiB" in text
        and "| lung_plane | 60 | 60 | 0.166 (×0.033) | 0.293 (×0.059) | 0.852 (×0.17) |" in text
    )
    # error against run time: the points by system (ablations counted apart) and the best row per budget
    pareto = blocks["Error against run time"]
    assert "60 points: 8 gigan, 44 cloud_baking, 8 ablation" in pareto
    assert "| GI map | 20 | cloud_baking | 0.002831 | 4.55 | codec × quality × profile × cache:" in pareto
    assert (
        "| frame | 90 | gigan | 0.1181 | 75.2 |" in pareto
        and "| ablation |" not in pareto
        and "#### Best configuration per time budget" in pareto
    )
    # Table 3, Fig. 6, Fig. 7, Fig. 9
    assert (
        "| gigan | lung_plane | 0.04092 | 0.9532 | 28.99 | — | — | — | 67.54 | model=gigan, ngf=16,"
        in blocks["GI-map quality, Fig. 6"]
    )
    assert "| 10 | 57.9 | 71.2 | 90.8 | 0.907 | 0.866 | 0.926 |" in blocks["Inference frequency, Table 3"]
    assert (
        "| lung_plane | structure-aware | 1.07 (2.36) | 37 | 0.896 |" in text
        and "| lung_plane | 0.78× | 2.01× |" in text
    )
    assert (
        "| lung_plane | 60° | 0.960 | 0.935 (87%) | 0.899 (87%) | 0.427 |" in text
        and "| lung_plane | 120° | 0.992 | 0.844 (99%) |" in text
    )
    # the stability counts agree with the CSV's rows, one case per (stage, case)
    cases = {
        (r["system"], r["config"]["case"]): r["config"]["status"]
        for r in read_rows(root / "results" / "stability" / "stability.csv")
    }
    statuses = list(cases.values())
    counts = (
        f"**{len(cases)} cases: {statuses.count('finite')} finite, {statuses.count('rejected')} cleanly rejected, "
        "0 failed**"
    )
    assert (
        counts == "**135 cases: 79 finite, 56 cleanly rejected, 0 failed**" and counts in blocks["Numerical stability"]
    )
    assert "| server | 19 | 5 | 14 | 0 |" in text
    # server, network self-test, scaling (projections labelled)
    assert "| hit_e2e (ms) |  | — | 2.33 | 4.77 | 5.58 | 10 |" in text and "load: 450.83 requests/s, 0 errors" in text
    assert (
        "26 of 26 targets met." in text
        and "| delay5 | one_way_delay (median) | 5 ms | 5.225 ms | \\|err\\| <= 1 ms | yes |" in text
    )
    assert "| local | 2 | 65.9 | 67 | 0.85 | 0.219 |" in text and "PROJECTED, not measured" in blocks["Scaling"]
    # the results folder is named as seen from where bench report ran, not by this machine's path
    assert (
        text.split("\n\n")[1]
        == "Generated from the CSV files under `results` by `bench report`; each block ends with the command that "
        "wrote its CSV."
    )


def test_the_readme_between_its_markers_is_replaced_the_rest_kept_and_a_second_run_changes_nothing(
    generated, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root, readme, results_md = generated
    text = readme.read_text()
    assert text.startswith(
        "# Project\n\nIntro.\n\n## Results\n\nWhat the numbers mean: hand-written, kept.\n\n" + BEGIN + "\n\n"
    )
    assert text.endswith("\n\n" + END + "\n\n## After\n\nKept too.\n") and "old hand-written tables" not in text
    assert text.count(BEGIN) == 1 and text.count(END) == 1
    assert results_md.read_text().strip() in text
    # a second run's part in the README (bench.report's measure), from the same folder on a copy of it: the same
    # results.md, and the README left as the first run made it
    again = tmp_path / "README.md"
    shutil.copy(readme, again)
    monkeypatch.chdir(root)
    second = results_markdown(root / "results", page=again)
    assert second.encode() == results_md.read_bytes()
    assert update_readme(again, second) is False and again.read_bytes() == readme.read_bytes()
    assert json.loads((root / "one" / "report.provenance.json").read_text())["files"][-1] == str(readme)


def test_a_malformed_csv_makes_only_its_block_say_so_and_a_missing_one_is_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    results = tmp_path / "results"
    shutil.copytree(FIXTURES, results)
    spoil_value(results / "warp" / "warp.csv")  # as the dashboard's test does
    (results / "scaling" / "scaling.csv").unlink()
    monkeypatch.chdir(tmp_path)
    blocks = sections(results_markdown(results))
    fig7 = blocks["Cost of warping, Fig. 7"]
    assert "\n" not in fig7 and fig7.startswith(
        "Not shown: malformed: warp/warp.csv: a row does not parse (ValueError:"
    )
    assert (
        blocks["Scaling"]
        == "Not in these results: missing: no scaling.csv under results; `bench scaling --out results` makes it."
    )
    for title, body in blocks.items():
        if title not in ("Cost of warping, Fig. 7", "Scaling"):
            assert body.splitlines()[-1].startswith("Command: `") and "|" in body, title


def test_a_readme_without_the_markers_is_refused_in_one_line_before_anything_is_built(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    results = tmp_path / "results"
    shutil.copytree(FIXTURES / "warp", results / "warp")
    readme = tmp_path / "README.md"
    readme.write_text("# Project\n\nno markers here\n")
    args = ("--results", str(results), "--out", str(tmp_path / "out"), "--readme", str(readme))
    assert exit_status(["bench", "report", *args], tmp_path) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in err, err
    assert f"has 0 '{BEGIN}' and 0 '{END}' lines" in errors[0] and "then run again" in errors[0]
    assert readme.read_text() == "# Project\n\nno markers here\n" and not (tmp_path / "out" / "report.html").exists()
    for text in (f"{BEGIN}\nonly the first\n", f"{END}\n{BEGIN}\n", f"{BEGIN}\n{END}\n{BEGIN}\n{END}\n"):
        readme.write_text(text)
        with pytest.raises(UserError, match="not one of each in that order") as caught:
            update_readme(readme, "new")
        assert "\n" not in str(caught.value) and str(caught.value).endswith("then run again")
        assert readme.read_text() == text


def test_ignored_folders_are_left_out_and_the_newest_of_the_rest_is_shown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    results = tmp_path / "results"
    for name, finished in (("warp", 1.0e9), ("side/warp_run", 2.0e9)):  # the side run is newer
        shutil.copytree(FIXTURES / "warp", results / name)
        provenance = results / name / "warp.provenance.json"
        provenance.write_text(
            provenance.read_text().replace('"finished_unix":', f'"finished_unix": {finished}, "was":', 1)
        )
    monkeypatch.chdir(tmp_path)
    fig7 = "Cost of warping, Fig. 7"
    assert sections(results_markdown(results))[fig7].endswith("; `side/warp_run/warp.csv`, the newest of 2 runs).")
    for ignore in (("side",), ("side/*",), ("*/warp_run",)):
        text = results_markdown(results, ignore)
        assert sections(text)[fig7].endswith(
            "2001-09-09 01:46:40 UTC, Intel(R) Xeon(R) Processor, 2 cores, "
            "Linux-6.18.44-fc-v669-x86_64-with-glibc2.36, Python 3.11.7; `warp/warp.csv`)."
        )
        assert f"bench report --results results --ignore {ignore[0]} --readme FILE" in text
    assert sections(results_markdown(results, ("warp", "side")))[fig7] == (
        "Not in these results: missing: no warp.csv under results (leaving out warp, side); "
        "`bench warp --out results` makes it."
    )


def test_figures_are_drawn_beside_the_page_and_linked_relative_to_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    results = tmp_path / "results"
    shutil.copytree(FIXTURES / "warp", results / "warp")
    (results / "warp" / "warp_old.png").write_bytes(b"\x89PNG a picture the bench does not declare")
    monkeypatch.chdir(tmp_path)
    page = tmp_path / "docs" / "results.md"
    text = results_markdown(results, figures=tmp_path / "docs" / "figures", page=page)
    assert sections(text)["Cost of warping, Fig. 7"].endswith("\n![warp](figures/warp/warp.png)")
    drawn = tmp_path / "docs" / "figures" / "warp" / "warp.png"  # drawn from the CSV's rows, as the bench declares
    assert drawn.read_bytes().startswith(b"\x89PNG") and not (drawn.parent / "warp_old.png").exists()
    assert text == results_markdown(results, figures=tmp_path / "docs" / "figures", page=page)  # same text again
    assert "![" not in results_markdown(results)  # without --figures: tables only
