"""Running console scripts, as subprocesses or in this process, and checking the one error policy
(docs/architecture.md, Errors)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from unittest import mock

import pytest

from tests.helpers.guards import HANG_GUARD_S

BIN = Path(sys.executable).parent


#: One subprocess run may take this long (imports of torch or Mitsuba dominate: ~1-2 s).
TIMEOUT_S = 120
#: The environment of every run: wide lines (usage errors are not wrapped), no colour codes.
SCRIPT_ENV = {"COLUMNS": "200", "NO_COLOR": "1"}


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
    env = os.environ | SCRIPT_ENV
    proc = subprocess.run([str(exe), *argv[1:]], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S, env=env)
    return Outcome(tuple(argv), proc.returncode, proc.stdout, proc.stderr, before, snapshot(cwd))


def script_main(name: str) -> Callable[[], object]:
    """The function console script ``name`` runs (its entry point in the installed package's metadata)."""
    [script] = entry_points(group="console_scripts", name=name)
    return script.load()


def exit_status(argv: list[str], cwd: Path | None = None) -> int:
    """Run :func:`script_main` of ``argv[0]`` in this process with ``sys.argv`` set to ``argv``, in ``cwd``
    (default: the current folder), and return its exit status; its output goes where the test captures it."""
    main = script_main(argv[0])
    with contextlib.chdir(cwd or Path.cwd()), mock.patch.object(sys, "argv", list(argv)):
        with pytest.raises(SystemExit) as exited:
            main()
    return int(exited.value.code or 0)


def run_main(argv: list[str], cwd: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]) -> Outcome:
    """:func:`run_script` in this process (:func:`exit_status`), with the same environment, its output read at
    the file descriptors. No interpreter start, so a run costs milliseconds; keep one :func:`run_script` per
    script for the real process."""
    before = snapshot(cwd)
    with monkeypatch.context() as patch:
        for name, value in SCRIPT_ENV.items():
            patch.setenv(name, value)
        capfd.readouterr()
        code = exit_status(argv, cwd)
        out, err = capfd.readouterr()
    return Outcome(tuple(argv), code, out, err, before, snapshot(cwd))


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


def signal_when(
    argv: list[str],
    cwd: Path,
    ready: Callable[[subprocess.Popen], bool],
    sig: int,
    env: dict[str, str] | None = None,
    delay_s: float = 0.0,
    poll_s: float = 0.05,
) -> tuple[int, str]:
    """Start console script ``argv`` (in ``env``), send ``sig`` ``delay_s`` after ``ready(proc)`` holds (looked at
    every ``poll_s``); its exit status and stderr."""
    proc = subprocess.Popen(
        [str(BIN / argv[0]), *argv[1:]], cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + HANG_GUARD_S
        while not ready(proc):
            assert proc.poll() is None, f"{argv[0]} ended before it was ready: {proc.communicate()}"
            assert time.monotonic() < deadline, f"{argv[0]} never became ready (hung)"
            time.sleep(poll_s)
        time.sleep(delay_s)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, err


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


def interpreter_started_marker(tmp_path: Path) -> tuple[dict[str, str], Path]:
    """An environment whose ``sitecustomize`` creates a file once CPython's own start (its ``site`` import) is
    over, and that file. A Ctrl-C before then is CPython's ("Fatal Python error: init_import_site"): no program
    can catch it, so a test's delays count from this file, not from the ``exec``."""
    hook, marker = tmp_path / "hook", tmp_path / "interpreter-started"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(f"open({str(marker)!r}, 'w').close()\n")
    return {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(hook), os.environ.get("PYTHONPATH")])),
    }, marker


def signal_after_start(argv: list[str], cwd: Path, sig: int, delay_s: float) -> tuple[int, str]:
    """Start console script ``argv``, send ``sig`` ``delay_s`` after CPython's own start
    (:func:`interpreter_started_marker`); its exit status and stderr."""
    env, started = interpreter_started_marker(Path(tempfile.mkdtemp(dir=cwd)))
    return signal_when(argv, cwd, lambda _: started.exists(), sig, env, delay_s, poll_s=0.002)
