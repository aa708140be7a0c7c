"""Timing conventions shared by every bench: warm-up runs, then repeats; report median and p95. Also a call's
peak memory."""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable
from typing import Any

import numpy as np


def time_repeats(fn: Callable[[], Any], repeats: int = 5, warmup: int = 1) -> tuple[list[float], Any]:
    """Run ``fn`` ``warmup`` times untimed, then ``repeats`` times timed; returns (seconds, last result)."""
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    result = None
    for _ in range(warmup):
        result = fn()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        samples.append(time.perf_counter() - t0)
    return samples, result


def summarize_ms(samples_s: list[float]) -> dict[str, float]:
    ms = np.asarray(samples_s, dtype=np.float64) * 1e3
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "n": float(len(ms))}


def peak_mib(fn: Callable[[], object]) -> float:
    """Peak traced allocation (MiB, :mod:`tracemalloc`: numpy's included) above the level before one call of
    ``fn``."""
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return (peak - base) / 2**20


class Stopwatch:
    """The one per-stage timer of the client loops: :meth:`lap` closes the running stage.

    ``ms`` maps each stage name to its milliseconds (summed if a stage is lapped twice), in the order the
    stages first ran::

        sw = Stopwatch()
        project()
        sw.lap("project")
        lookup()
        sw.lap("lookup")  # sw.ms == {"project": ..., "lookup": ...}
    """

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, stage: str) -> float:
        """Record the time since the previous lap (or the start, or :meth:`restart`) as ``stage``; returns it in ms."""
        now = time.perf_counter()
        ms = (now - self._t) * 1e3
        self.ms[stage] = self.ms.get(stage, 0.0) + ms
        self._t = now
        return ms

    def restart(self) -> None:
        """Start the next stage now: time since the last lap is not counted (e.g. untimed evaluation)."""
        self._t = time.perf_counter()
