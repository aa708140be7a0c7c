"""The results folder the report tests read (``tests/bench/fixtures/report_results``: small real outputs of the
benches, their commands in each provenance JSON) and the one ``bench report`` of all of it that the dashboard's
tests (test_report.py) and the README's (test_report_md.py) share: drawing every section's figures is the
costly part, so it is done once per test run."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest

from bench.report_md import BEGIN, END
from tests.helpers.cli import exit_status
from tests.helpers.shared import shared_artifact

FIXTURES = Path(__file__).parent / "fixtures" / "report_results"
#: A README with the results markers between hand-written parts.
README = (
    "# Project\n\nIntro.\n\n## Results\n\nWhat the numbers mean: hand-written, kept.\n\n"
    f"{BEGIN}\nold hand-written tables\n{END}\n\n## After\n\nKept too.\n"
)


def spoil_value(path: Path, row: int = 3) -> None:
    """Make the value of one row of a results CSV unparsable."""
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    rows[row]["value"] = "not-a-number"
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _report_everything(root: Path) -> None:
    shutil.copytree(FIXTURES, root / "results")
    (root / "README.md").write_text(README)
    args = ("--results", str(root / "results"), "--out", str(root / "one"), "--readme", str(root / "README.md"))
    assert exit_status(["bench", "report", *args], root) == 0  # run from root: the Markdown names the folder `results`


def report_of_everything(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding ``results`` (the fixtures), ``README.md`` (:data:`README` before the run) and ``one``
    (report.html, report.csv, results.md): ``bench report --results results --out one --readme README.md`` run
    from that folder. Read-only: copy what a test changes."""
    return shared_artifact(tmp_path_factory, "bench_report_of_the_fixtures", _report_everything)
