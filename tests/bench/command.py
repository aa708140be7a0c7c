"""The ``bench`` console script's ``main`` (:mod:`bench.cli`) run in this process, under the one error policy:
what a test sees of a run is its exit status, its output (``capsys``) and its files, without a process start
that imports every bench again. One test per console script still starts the installed script as a process
(tests/bench/test_runner.py, the bad-input checks)."""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from unittest import mock

import pytest

from bench.cli import main


def bench_main(*args: str, cwd: Path | None = None) -> int:
    """Run ``bench ARGS`` (in ``cwd``, default the current folder) and return its exit status."""
    with (
        contextlib.chdir(cwd or os.getcwd()),
        mock.patch.object(sys, "argv", ["bench", *args]),
        pytest.raises(SystemExit) as exited,
    ):
        main()
    return exited.value.code
