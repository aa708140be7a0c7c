"""`bench stability`: the verdicts of its case runner, and a --quick run with every case finite or cleanly rejected."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench.stability import BENCH, PASSED, STAGES, counts, judge, record, summary, verdict
from gicore.error_policy import UserError
from gicore.present import write_files
from gicore.results import Results, read_rows
from gicore.stability import Case, Outcome, Rejected
from network_sim.stability_cases import DEAD_LINKS

BIN = Path(sys.executable).parent


def _case(expect: str, run) -> Case:
    return Case("tonemap", "probe", expect, run)


def test_judge_passes_finite_outputs_within_their_bound_and_clean_rejections() -> None:
    ok = judge(_case("finite", lambda: Outcome((np.ones(3),), 1e-7, "rel", 1e-6)), 5.0)
    assert (ok.status, ok.finite, ok.error, ok.bound) == ("finite", True, 1e-7, 1e-6)
    for exc in (
        ValueError("x must be finite"),
        UserError("--x is bad", "fix it"),
        Rejected("HTTP 422 at body/camera/fov: too wide"),
    ):

        def refuse(e: Exception = exc) -> Outcome:
            raise e

        v = judge(_case("rejected", refuse), 5.0)
        assert v.status == "rejected" and v.passed and str(exc).split(":")[0] in v.message


@pytest.mark.parametrize(
    ("expect", "run", "status"),
    [
        ("finite", lambda: Outcome((np.array([1.0, math.nan]),)), "FAIL: non-finite output"),
        ("finite", lambda: Outcome((np.ones(2),), 0.5, "rmse", 0.1), "FAIL: error above bound"),
        ("finite", lambda: Outcome((np.ones(2),), math.nan, "rmse", None), "FAIL: error above bound"),
        ("finite", lambda: {}["missing"], "FAIL: crashed"),
        ("finite", lambda: (_ for _ in ()).throw(ValueError("refused")), "FAIL: valid input refused"),
        ("rejected", lambda: Outcome((np.ones(2),)), "FAIL: invalid input accepted"),
        ("rejected", lambda: 1 / 0, "FAIL: crashed"),
    ],
)
def test_judge_fails_what_is_not_the_expected_behaviour(expect: str, run, status: str) -> None:
    v = judge(_case(expect, run), 5.0)
    assert v.status == status and not v.passed


def test_a_hanging_case_is_cut_off_at_its_time_limit() -> None:
    v = judge(_case("finite", lambda: time.sleep(30)), 0.3)
    assert v.status == "FAIL: hang"  # judged while the case still ran: cut off, not waited for


def test_failed_cases_are_written_then_named_in_one_user_error(tmp_path: Path) -> None:
    res = Results("stability", tmp_path)
    cases = [
        _case("finite", lambda: Outcome((np.ones(2),), 0.0, "max", 0.0)),
        Case("codecs", "jpeg: broken", "finite", lambda: {}["x"]),
        Case("server", "NaN eye", "rejected", lambda: Outcome((np.ones(1),))),
    ]
    for case in cases:
        record(res, "none", case, judge(case, 5.0))
    rows = read_rows(res.write())
    write_files("stability", BENCH.parts, rows, tmp_path)
    with pytest.raises(
        UserError,
        match=r"2 of 3 stability cases failed: codecs/jpeg: broken \(crashed\); "
        r"server/NaN eye \(invalid input accepted\)",
    ):
        verdict(rows)
    table = (tmp_path / "stability.md").read_text()
    assert "3 cases, 1 finite, 0 cleanly rejected, 2 failed" in table and "KeyError" in table
    assert counts(summary(read_rows(tmp_path / "stability.csv"))) == {
        "cases": 3,
        "finite": 1,
        "rejected": 0,
        "failed": 2,
    }


@pytest.mark.slow
def test_quick_run_every_case_finite_or_cleanly_rejected(tmp_path: Path) -> None:
    proc = subprocess.run(
        [str(BIN / "bench"), "stability", "--quick", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stdout + proc.stderr
    entries = summary(read_rows(tmp_path / "stability.csv"))
    n = counts(entries)
    assert n["failed"] == 0 and n["cases"] >= 120 and n["finite"] >= 60 and n["rejected"] >= 45, n
    assert {e["stage"] for e in entries} == set(STAGES)
    for e in entries:
        assert e["status"] in PASSED  # a case that hung past the bench's limit would be "FAIL: hang"
        if e["status"] == "rejected":
            assert len(e["message"]) > 15, e  # says what was wrong
    by_case = {(e["stage"], e["case"]): e for e in entries}
    # references: the identity warp and the clip range are exact, the light scales the radiance linearly
    for key in [
        ("warp", "structure-aware: zero motion (identity)"),
        ("warp", "pixel-level: zero motion (identity)"),
        ("render", "near/far 1e-4/1e4"),
    ]:
        assert by_case[key]["error"] is not None and by_case[key]["error"] <= by_case[key]["bound"]
    assert by_case["render", "light ×1e4"]["error"] < 1e-3
    # dead links end in the client's 1 s timeouts, not hangs (a hang past the case limit would be "FAIL: hang")
    for name in DEAD_LINKS:
        assert "timeout" in by_case["network", f"proxy + client: {name}"]["message"]
    # the server bakes only lights the scene's light can reach: one touching a surface elsewhere is refused
    touching = by_case["server", "light 1e-4 from a surface (outside the scene's light range)"]
    assert touching["status"] == "rejected" and "outside the light range" in touching["message"]
    assert by_case["server", "NaN eye"]["message"].startswith("Rejected: HTTP 422 at body/camera/eye")
    assert (tmp_path / "stability.md").read_text().startswith(f"## Numerical stability: {n['cases']} cases")
