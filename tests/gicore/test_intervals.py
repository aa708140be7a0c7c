"""Bootstrap intervals of `bench latency`'s ratios of totals and crossover RTTs (gicore.intervals): coverage and
width on synthetic lognormal samples, reproducibility, too few samples, and how the rows and tables show them."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bench.latency_record import CLOUD, GIGAN, _record_cloud_stages, _record_crossover
from bench.latency_tables import CROSSOVERS, SHORT, TABLE1
from gicore.intervals import LEVEL, RESAMPLES, interval_over_runs, ratio_interval
from gicore.present.markdown import table_text
from gicore.results import Results, read_rows
from network_sim.exchange import CloudCost, crossover_interval

#: Lognormal totals (ms): median and log-spread of each system, and how many maps each measured.
GIGAN_MEDIAN, GIGAN_SIGMA, GIGAN_MAPS = 45.0, 0.3, 30
CLOUD_MEDIAN, CLOUD_SIGMA, CLOUD_MAPS = 60.0, 0.5, 40


def lognormal(rng: np.random.Generator, median: float, sigma: float, n: int) -> np.ndarray:
    return rng.lognormal(math.log(median), sigma, n)


def test_the_ratio_interval_covers_the_true_ratio_of_medians_and_is_as_wide_as_the_medians_spread() -> None:
    true_ratio = CLOUD_MEDIAN / GIGAN_MEDIAN
    covered, log_widths = 0, []
    for seed in range(200):
        rng = np.random.default_rng(seed)
        cloud = lognormal(rng, CLOUD_MEDIAN, CLOUD_SIGMA, CLOUD_MAPS)
        gigan = lognormal(rng, GIGAN_MEDIAN, GIGAN_SIGMA, GIGAN_MAPS)
        interval = ratio_interval(cloud, gigan, seed, resamples=1000)
        assert interval is not None and interval.low < interval.high
        covered += interval.spans(true_ratio)
        log_widths.append(math.log(interval.high / interval.low))
    assert covered >= 0.9 * 200, covered
    # a median's standard error is sqrt(pi / 2) sigma / sqrt(n) in the log: the 95 % width of the log-ratio
    expected = 2 * 1.96 * math.sqrt(math.pi / 2 * (CLOUD_SIGMA**2 / CLOUD_MAPS + GIGAN_SIGMA**2 / GIGAN_MAPS))
    assert 0.6 < float(np.mean(log_widths)) / expected < 1.5


def test_four_times_the_maps_halve_the_interval() -> None:
    def width(n: int) -> float:
        widths = []
        for seed in range(40):
            rng = np.random.default_rng(seed)
            cloud, gigan = lognormal(rng, CLOUD_MEDIAN, CLOUD_SIGMA, n), lognormal(rng, GIGAN_MEDIAN, GIGAN_SIGMA, n)
            interval = ratio_interval(cloud, gigan, seed, resamples=500)
            assert interval is not None
            widths.append(math.log(interval.high / interval.low))
        return float(np.mean(widths))

    assert 0.35 < width(160) / width(40) < 0.7


def test_the_interval_over_runs_covers_the_mean_of_the_runs() -> None:
    covered = 0
    for seed in range(200):
        runs = np.random.default_rng(seed).normal(1.2, 0.1, 20)
        interval = interval_over_runs(runs, seed, resamples=1000)
        assert interval is not None
        covered += interval.spans(1.2)
    assert covered >= 0.88 * 200, covered


def cloud_stages(rng: np.random.Generator, n: int, median: float = CLOUD_MEDIAN) -> dict[str, list[float]]:
    """A cloud client's stage samples per shown request: what the record and the link model read."""
    total = lognormal(rng, median, CLOUD_SIGMA, n)
    transmission = 0.4 * total
    server = rng.uniform(1.0, 5.0, n)
    return {
        "total": list(total),
        "transmission": list(transmission),
        "request": list(0.5 * transmission),
        "transfer": list(0.5 * transmission),
        "server": list(server),
        "lookup": list(server),
        "bytes_up": [400.0] * n,
        "bytes_down": list(rng.uniform(2e4, 4e4, n)),
    }


def test_the_crossover_interval_holds_the_measured_crossover_and_collapses_without_spread() -> None:
    rng = np.random.default_rng(3)
    stages, gigan = cloud_stages(rng, 40), lognormal(rng, 100.0, GIGAN_SIGMA, 30)
    interval = crossover_interval(stages, gigan, None, 7, resamples=200)
    measured = CloudCost.of(stages).crossover_rtt_ms(float(np.median(gigan)), None)
    assert interval is not None and interval.low < measured < interval.high
    assert interval == crossover_interval(stages, gigan, None, 7, resamples=200)
    same = {name: [values[0]] * 5 for name, values in stages.items()}
    fixed = crossover_interval(same, [100.0] * 5, None, 7, resamples=50)
    assert fixed is not None
    expected = CloudCost.of(same).crossover_rtt_ms(100.0, None)
    assert fixed.low == fixed.high == pytest.approx(expected)


def test_fewer_than_three_values_make_no_interval() -> None:
    three, two = [40.0, 50.0, 60.0], [40.0, 50.0]
    assert ratio_interval(two, three, 0) is None and ratio_interval(three, two, 0) is None
    assert ratio_interval(three, three, 0) is not None
    assert interval_over_runs(two, 0) is None and interval_over_runs(three, 0) is not None
    stages = cloud_stages(np.random.default_rng(0), 2)
    assert crossover_interval(stages, three, None, 0, resamples=20) is None


def test_the_same_seed_gives_the_same_interval_and_another_seed_another() -> None:
    rng = np.random.default_rng(0)
    cloud, gigan = lognormal(rng, CLOUD_MEDIAN, CLOUD_SIGMA, 40), lognormal(rng, GIGAN_MEDIAN, GIGAN_SIGMA, 30)
    assert ratio_interval(cloud, gigan, 5) == ratio_interval(cloud, gigan, 5)
    assert ratio_interval(cloud, gigan, 5) != ratio_interval(cloud, gigan, 6)
    assert interval_over_runs(gigan, [5, 1]) == interval_over_runs(gigan, [5, 1]) != interval_over_runs(gigan, [5, 2])


# -- the rows and the tables --------------------------------------------------------------------------------
def record_run(tmp_path: Path, miss_maps: int = 40) -> list[dict]:
    """The rows of a run on one renderer and profile: GIGAN's totals, a cloud hit as fast as GIGAN (its ratio's
    interval holds 1), a cloud miss ten times slower on ``miss_maps`` maps, and the crossovers."""
    rng = np.random.default_rng(1)
    res = Results("latency", tmp_path, seed=0)
    gigan = lognormal(rng, GIGAN_MEDIAN, GIGAN_SIGMA, GIGAN_MAPS)
    common = {"renderer": "gl", "resolution": 64}
    res.add_timing(system=GIGAN, scene="s", metric="total", samples_s=list(gigan / 1e3), profile="none", **common)
    cfg = SimpleNamespace(sweep_rate_mbit=None, sweep_max_rtt_ms=100.0)
    for cache, median, maps in (("hit", GIGAN_MEDIAN, 40), ("miss", 10 * GIGAN_MEDIAN, miss_maps)):
        samples = cloud_stages(rng, maps, median)
        _record_cloud_stages(res, "s", "lan", [samples], [list(gigan)], {"profile": "lan", "cache": cache} | common)
        _record_crossover(res, "s", cfg, [samples], [list(gigan)], {"cache": cache, "rate_mbit": None} | common)
    res.write()
    return read_rows(res.csv_path)


def test_the_rows_hold_each_interval_beside_its_value(tmp_path: Path) -> None:
    rows = record_run(tmp_path)
    ratio = f"{CLOUD}/{GIGAN}"
    for metric, stat in (("total_ratio", "median"), ("crossover_rtt", "model")):
        for cache in ("hit", "miss"):
            [value] = [r for r in rows if (r["system"], r["metric"], r["stat"]) == (ratio, metric, stat)
                       and r["config"]["cache"] == cache]  # fmt: skip
            bounds = {
                r["stat"]: r
                for r in rows
                if r["metric"] == metric and r["stat"].startswith("ci_") and r["config"]["cache"] == cache
            }
            assert set(bounds) == {"ci_low", "ci_high"}
            for r in bounds.values():
                assert r["system"] == ratio and r["unit"] == value["unit"]
                assert r["config"] == value["config"] | {"ci": LEVEL, "resamples": RESAMPLES, "ci_over": "maps"}
            assert bounds["ci_low"]["value"] <= value["value"] <= bounds["ci_high"]["value"]


def ratio_cells(rows: list[dict]) -> list[str]:
    """Table 1's ratio-of-totals cells: GIGAN's, the cloud hit's, the cloud miss's."""
    line = next(line for line in table_text(TABLE1, rows, 2).splitlines() if line.startswith("| ratio of totals"))
    return [cell.strip() for cell in line.strip(" |").split("|")][1:]


def test_the_tables_show_the_intervals_and_no_clear_winner_where_one_spans_1(tmp_path: Path) -> None:
    rows = record_run(tmp_path)
    _, hit, miss = ratio_cells(rows)
    low, high = (float(v) for v in hit[hit.index("[") + 1 : hit.index("]")].split(", "))
    assert low <= 1 <= high and hit.endswith("] no clear winner"), hit
    assert "no clear winner" not in miss and miss.count("[") == 1 and miss.endswith("]"), miss
    short = table_text(SHORT, rows, 2)
    assert f"| {hit} / {miss} |" in short and "the 95 % percentile-bootstrap interval (2000 resamples" in short
    crossings = table_text(CROSSOVERS, rows, 2)
    assert "| gl | miss | 0 [0, 0] (GIGAN is faster at any RTT) |" in crossings, crossings


def test_too_few_maps_say_so_and_runs_before_the_intervals_show_as_they_did(tmp_path: Path) -> None:
    rows = record_run(tmp_path, miss_maps=2)
    _, hit, miss = ratio_cells(rows)
    assert miss.endswith(" (n < 3)") and "[" in hit, (hit, miss)
    # GIGAN's column, the hit's, the miss's
    rests = f"| — | 40 / {GIGAN_MAPS} | too few maps for an interval: raise --frames |"
    assert f"| the interval rests on (maps: cloud / GIGAN) {rests}" in table_text(TABLE1, rows, 2)
    assert "| gl | miss | 0 (n < 3) (GIGAN is faster at any RTT) |" in table_text(CROSSOVERS, rows, 2)
    older = [r for r in rows if not r["stat"].startswith("ci_")]
    ratios = {r["config"]["cache"]: r["value"] for r in older if r["metric"] == "total_ratio"}
    assert ratio_cells(older) == ["—", f"{ratios['hit']:.2f}", f"{ratios['miss']:.2f}"]
    assert "| gl | miss | 0 (GIGAN is faster at any RTT) |" in table_text(CROSSOVERS, older, 2)
    assert "interval" not in table_text(SHORT, older, 2) + table_text(TABLE1, older, 2)
