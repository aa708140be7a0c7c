"""Percentile-bootstrap confidence intervals of `bench latency`'s ratios of totals and crossover RTTs (the latter
in :func:`network_sim.exchange.crossover_interval`, with the link model), the rows that record them and the cell
text that shows them.

Each system's per-map samples are independent, so a resample draws each system's maps with replacement apart
(a cloud map keeps its stages together) and recomputes the statistic; the interval is the resampled statistics'
``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles, taken as order statistics (no interpolation: a crossover
may be infinite). Pooling whole runs instead, :func:`interval_over_runs` resamples the runs' own values. Every
draw comes from a generator seeded by the caller (the run's seed): the same samples and seed give the same
interval. A sample of fewer than :data:`MIN_SAMPLES` values gets no interval (None).

The rows: beside the row of the statistic itself, ``stat`` ``ci_low`` and ``ci_high`` with the same system,
metric and config plus ``ci`` (the level), ``resamples`` and ``ci_over`` (what was resampled: ``maps`` or ``runs``;
:func:`add_interval`)."""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from gicore.present.declarations import Rows, matches
from gicore.results import Results

LEVEL = 0.95
RESAMPLES = 2000
#: Fewer values than this make no interval: a resample of two values has three distinct medians.
MIN_SAMPLES = 3
#: Resampled values drawn at once: the batch of resamples of a large sample stays a few MiB.
_BATCH = 1 << 19
#: A seed: the run's seed alone, or with further integers that set one interval's stream apart.
Seed = int | Sequence[int]


@dataclass(frozen=True)
class Interval:
    """A statistic's interval at ``level`` from ``resamples`` resamples of each system's ``maps`` or of the
    repeated ``runs`` (``over``)."""

    low: float
    high: float
    level: float
    resamples: int
    over: Literal["maps", "runs"] = "maps"

    def spans(self, value: float) -> bool:
        return self.low <= value <= self.high


def stream(seed: int, *key: Any) -> list[int]:
    """``seed`` with a stable number of ``key`` (JSON), so each interval of a run draws its own resamples while
    staying reproducible (Python's ``hash`` of a string changes between processes)."""
    return [seed, zlib.crc32(json.dumps(key, sort_keys=True, default=str).encode())]


def ratio_interval(
    num_samples: Sequence[float],
    den_samples: Sequence[float],
    seed: Seed,
    level: float = LEVEL,
    resamples: int = RESAMPLES,
) -> Interval | None:
    """The interval of median(num) / median(den), the two samples independent (None: either has fewer than
    :data:`MIN_SAMPLES` values)."""
    num, den = values_of(num_samples), values_of(den_samples)
    if min(num.size, den.size) < MIN_SAMPLES:
        return None
    rng = np.random.default_rng(seed)
    medians = [resampled(v, rng, resamples, np.median) for v in (num, den)]
    return quantiles(medians[0] / medians[1], level, resamples)


def interval_over_runs(
    values: Sequence[float], seed: Seed, level: float = LEVEL, resamples: int = RESAMPLES
) -> Interval | None:
    """The interval of the mean of per-run ``values`` (e.g. each run's ratio of totals), runs resampled (None:
    fewer than :data:`MIN_SAMPLES` runs)."""
    runs = values_of(values)
    if runs.size < MIN_SAMPLES:
        return None
    interval = quantiles(resampled(runs, np.random.default_rng(seed), resamples, np.mean), level, resamples)
    return replace(interval, over="runs")


def add_interval(res: Results, interval: Interval | None, **row: Any) -> None:
    """The ``ci_low`` and ``ci_high`` rows of ``interval`` beside the row of ``row``'s system, scene, metric, unit
    and config (none for no interval)."""
    if interval is None:
        return
    for stat, value in (("ci_low", interval.low), ("ci_high", interval.high)):
        res.add(**row, stat=stat, value=value, ci=interval.level, resamples=interval.resamples, ci_over=interval.over)


def recorded(rows: Rows, system: str, metric: str, **config: Any) -> Interval | None:
    """The interval :func:`add_interval` recorded for the row of ``system``, ``metric`` and ``config`` (None:
    none)."""
    bounds: dict[str, dict[str, Any]] = {}
    for r in rows:
        if r["system"] == system and r["stat"] in ("ci_low", "ci_high") and matches(r, metric, **config):
            bounds.setdefault(r["stat"], r)
    if len(bounds) < 2:
        return None
    low, high = bounds["ci_low"], bounds["ci_high"]
    over = low["config"].get("ci_over", "maps")  # runs from before the repeats resampled maps
    return Interval(low["value"], high["value"], low["config"]["ci"], low["config"]["resamples"], over)


def level_of(rows: Rows, metric: str) -> float | None:
    """The level of the run's intervals of ``metric`` (None: it recorded none)."""
    return next((r["config"]["ci"] for r in rows if matches(r, metric, "ci_low")), None)


def legend(rows: Rows, metric: str, maps: str) -> str:
    """A table's note on its intervals of ``metric``, saying what was resampled: ``maps`` (what the per-map
    bootstrap draws) or the repeated runs' own values; empty where the run recorded none."""
    lows = [r for r in rows if matches(r, metric, "ci_low")]
    if not lows:
        return ""
    config = lows[0]["config"]
    level, resamples = config["ci"] * 100, config["resamples"]
    runs = f"the {config.get('repeats')} runs' own values, each from its run's maps (the interval of their mean)"
    over = dict.fromkeys(r["config"].get("ci_over", "maps") for r in lows)
    resampled = " or ".join(runs if o == "runs" else maps for o in over)
    return f"In square brackets: the {level:g} % percentile-bootstrap interval ({resamples} resamples of {resampled})."


def too_few(rows: Rows, metric: str, counts: Sequence[float | None]) -> bool:
    """Whether samples of sizes ``counts`` (a missing one as 0) made no interval of ``metric``: only in a run that
    recorded intervals of it (older runs recorded none)."""
    return min(n or 0 for n in counts) < MIN_SAMPLES and level_of(rows, metric) is not None


def suffix(interval: Interval | None, few: bool, fmt: str, even: float | None = None) -> str:
    """What follows a value: its interval in brackets, and ``no clear winner`` where it holds ``even`` (the value
    at which neither system is faster); ``(n < 3)`` where ``few`` samples made none; else nothing."""
    if interval is None:
        return f" (n < {MIN_SAMPLES})" if few else ""
    text = f" [{_number(interval.low, fmt)}, {_number(interval.high, fmt)}]"
    return text + (" no clear winner" if even is not None and interval.spans(even) else "")


def cell(
    rows: Rows,
    system: str,
    metric: str,
    stat: str,
    counts: Sequence[float | None],
    fmt: str,
    even: float | None = None,
    **config: Any,
) -> str | None:
    """The ``stat`` row of ``system``, ``metric`` and ``config`` as ``fmt`` with its :func:`suffix`, its samples'
    sizes ``counts``; None (a dash) without the row."""
    value = next((r["value"] for r in rows if r["system"] == system and matches(r, metric, stat, **config)), None)
    if value is None:
        return None
    interval = recorded(rows, system, metric, **config)
    return _number(value, fmt) + suffix(interval, too_few(rows, metric, counts), fmt, even)


def _number(value: float, fmt: str) -> str:
    return "∞" if math.isinf(value) else format(value, fmt)


def values_of(samples: Sequence[float]) -> np.ndarray:
    return np.asarray(samples, dtype=np.float64).ravel()


def resampled(
    values: np.ndarray, rng: np.random.Generator, resamples: int, statistic: Callable[..., np.ndarray]
) -> np.ndarray:
    """``statistic`` of ``resamples`` draws of ``values`` with replacement, drawn in batches."""
    per_batch = max(1, _BATCH // values.size)
    out = []
    for start in range(0, resamples, per_batch):
        picked = rng.integers(0, values.size, (min(per_batch, resamples - start), values.size))
        out.append(statistic(values[picked], axis=1))
    return np.concatenate(out)


def quantiles(statistics: np.ndarray, level: float, resamples: int) -> Interval:
    low, high = np.quantile(statistics, [(1 - level) / 2, (1 + level) / 2], method="inverted_cdf")
    return Interval(float(low), float(high), level, resamples)
