"""Running console scripts as subprocesses and checking the one error policy (docs/architecture.md, Errors)."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

BIN = Path(sys.executable).parent


#: One subprocess run may take this long (imports of torch or Mitsuba dominate: ~1-2 s).
TIMEOUT_S = 120


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``root`` with its size and modification time, and every folder (whose own
    modification time changes when a run takes and drops its lock file, so it is left out)."""
    return {
        str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() else (-1, 0)
        for p in root.rglob("*")
    }


@dataclass(frozen=True)
class Outcome:
    """What one console-script run did: its status, output, and the workspace before and after."""

    argv: tuple[str, ...]
    returncode: int
    stdout: str
    stderr: str
    before: dict[str, tuple[int, int]]
    after: dict[str, tuple[int, int]]


def run_script(argv: list[str], cwd: Path) -> Outcome:
    """Run console script ``argv[0]`` (from this interpreter's bin folder) with ``argv[1:]`` in ``cwd``."""
    exe = BIN / argv[0]
    assert exe.is_file(), f"console script {argv[0]} is not installed (pip install -e .)"
    before = snapshot(cwd)
    env = os.environ | {"COLUMNS": "200", "NO_COLOR": "1"}
    proc = subprocess.run([str(exe), *argv[1:]], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S, env=env)
    return Outcome(tuple(argv), proc.returncode, proc.stdout, proc.stderr, before, snapshot(cwd))


def check_user_error(outcome: Outcome, culprit: str) -> str:
    """Assert a clean user error that names ``culprit`` and left the workspace untouched; returns the line."""
    output = outcome.stdout + outcome.stderr
    assert "Traceback" not in output, output
    errors = [line for line in outcome.stderr.splitlines() if line.startswith("error:")]
    assert outcome.returncode == 2, f"exit status {outcome.returncode}, expected 2:\n{output}"
    assert len(errors) == 1, f"expected exactly one error line:\n{output}"
    assert culprit in errors[0], f"the error line does not name {culprit!r}: {errors[0]}"
    changed = sorted(set(outcome.after.items()) ^ set(outcome.before.items()))
    assert not changed, f"{list(outcome.argv)} changed the workspace: {changed}"
    return errors[0]


def assert_user_error(argv: list[str], culprit: str, cwd: Path) -> str:
    """Run ``argv`` in ``cwd`` (see :func:`run_script`) and :func:`check_user_error` it; returns the error line."""
    return check_user_error(run_script(argv, cwd), culprit)


def run_command(cmd: list[str]) -> subprocess.CompletedProcess:
    """Run ``cmd`` (a full argv) and capture its output, without checking its status."""
    return subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=90)


def assert_error_line(result: subprocess.CompletedProcess, *culprits: str) -> None:
    """Exit 2, exactly one ``error:`` line (the last) naming every culprit, no traceback."""
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len([line for line in lines if line.startswith("error:")]) == 1 and lines[-1].startswith("error:"), (
        result.stderr
    )
    assert "Traceback" not in result.stderr
    for culprit in culprits:
        assert culprit in lines[-1], (culprit, lines[-1])
