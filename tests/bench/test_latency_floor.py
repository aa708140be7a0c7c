"""`bench latency`'s stages alone beside the loop (bench.latency_floor): a stage slowed in the loop shows as its
inflation and is named in a warning, the floors add up the stages alone, and the targets say met or MISSED."""

from __future__ import annotations

import pytest

from bench.latency_floor import INFLATION_WARN, floors, record_alone, record_floor_ratios, record_targets
from bench.latency_record import CLOUD, GIGAN
from gicore.results import Results

STAGES = {"request": 2.0, "transfer": 0.2, "lookup": 0.1, "read": 0.1, "server_other": 0.1, "decode": 1.0}
STAGES |= {"di": 5.0, "warp": 4.0, "blend": 0.3}
GIGAN_STAGES = {"di": 5.0, "gi_render": 6.0, "inference": 10.0, "warp": 4.0, "blend": 0.3}


def _results(tmp_path, slowed: dict[str, float]) -> Results:
    """Loop medians as bench latency's record() writes them, every cloud stage as alone except ``slowed``."""
    res = Results("latency", tmp_path, seed=0)
    where = {"resolution": 64, "renderer": "gl"}
    loop = STAGES | slowed
    for stage, ms in loop.items():
        res.add(system=CLOUD, scene="s", metric=stage, value=ms, unit="ms", stat="median", profile="lan",
                cache="hit", **where)  # fmt: skip
    res.add(system=CLOUD, scene="s", metric="transmission", value=loop["request"] + loop["transfer"], unit="ms",
            stat="median", profile="lan", cache="hit", **where)  # fmt: skip
    res.add(system=CLOUD, scene="s", metric="total", value=sum(loop.values()), unit="ms", stat="median",
            profile="lan", cache="hit", **where)  # fmt: skip
    for stage, ms in GIGAN_STAGES.items():
        res.add(system=GIGAN, scene="s", metric=stage, value=ms, unit="ms", stat="median", profile="none", **where)
    res.add(system=GIGAN, scene="s", metric="total", value=sum(GIGAN_STAGES.values()), unit="ms", stat="median",
            profile="none", **where)  # fmt: skip
    ratio = sum(loop.values()) / sum(GIGAN_STAGES.values())
    res.add(system=f"{CLOUD}/{GIGAN}", scene="s", metric="total_ratio", value=ratio, unit="1", stat="median",
            profile="lan", cache="hit", rtt_ms=0.5, **where)  # fmt: skip
    for metric in ("bytes_up", "bytes_down"):
        res.add(system=CLOUD, scene="s", metric=metric, value=1000.0, unit="B", stat="median", profile="lan",
                cache="hit", **where)  # fmt: skip
    res.add(system=f"{CLOUD}/{GIGAN}", scene="s", metric="crossover_rtt", value=5.0, unit="ms", stat="model",
            cache="hit", rate_mbit=None, **where)  # fmt: skip
    return res


def _alone() -> dict:
    cloud = {s: [ms * f for f in (0.9, 1.0, 1.1)] for s, ms in STAGES.items()}
    cloud |= {"transmission": [2.2] * 3, "server": [0.3] * 3}
    gigan = {s: [ms] * 3 for s, ms in GIGAN_STAGES.items()}
    return {(CLOUD, "lan", "gl"): cloud, (GIGAN, "none", "gl"): gigan}


def test_a_stage_slowed_in_the_loop_shows_as_its_inflation_and_is_named(tmp_path) -> None:
    res = _results(tmp_path, {"decode": 6.0})  # the decode waited 5 ms for the frame loop
    warnings = record_alone(res, "s", _alone())
    inflation = {r["metric"]: r["value"] for r in res.rows if r["stat"] == "inflation" and r["system"] == CLOUD}
    assert inflation["decode"] == pytest.approx(6.0)
    assert all(v == pytest.approx(1.0) for s, v in inflation.items() if s not in ("decode", "transmission"))
    assert len(warnings) == 1 and "decode" in warnings[0] and "6.0x" in warnings[0]
    # an unslowed run names none, and a tiny stage over the ratio but within the timer's noise is not named
    clean = _results(tmp_path, {"lookup": 0.1 * (INFLATION_WARN + 1)})
    assert record_alone(clean, "s", _alone()) == []


def test_the_floors_add_up_the_stages_alone_and_their_ratio_and_crossover_follow(tmp_path) -> None:
    res = _results(tmp_path, {"decode": 6.0})
    record_alone(res, "s", _alone())
    record_floor_ratios(res, "s", _alone())
    floor = {(r["system"], r["metric"]): r["value"] for r in res.rows if r["stat"] == "alone"}
    assert floor[CLOUD, "total"] == pytest.approx(sum(STAGES.values()))
    assert floor[GIGAN, "total"] == pytest.approx(sum(GIGAN_STAGES.values()))
    assert floor[f"{CLOUD}/{GIGAN}", "total_ratio"] == pytest.approx(sum(STAGES.values()) / sum(GIGAN_STAGES.values()))
    # at the floor the cloud hit is cheaper than in the loop: its crossover moves to a larger RTT
    assert floor[f"{CLOUD}/{GIGAN}", "crossover_rtt"] > 0
    # the floors' ratio has its bootstrap interval (each stage alone resampled apart), around the ratio itself
    bounds = {r["stat"]: r["value"] for r in res.rows if r["stat"] in ("alone_ci_low", "alone_ci_high")}
    ratio = floor[f"{CLOUD}/{GIGAN}", "total_ratio"]
    low, high = bounds["alone_ci_low"], bounds["alone_ci_high"]
    assert low <= ratio <= high and low < high
    shown = floors([{**r, "config": dict(r["config"])} for r in res.rows])
    assert shown[0]["ratio_floor"] == f"{ratio:.2f} [{low:.2f}, {high:.2f}]"


def test_targets_say_met_or_missed_and_whether_they_apply(tmp_path) -> None:
    res = _results(tmp_path, {"decode": 6.0, "request": 2.5})
    record_alone(res, "s", _alone())
    rows = record_targets(res, "s", {"decode": [1.2, 1.3], "library": [1.0, 1.0]}, client_cores=1, where="test box")
    met = {r["metric"]: (r["value"], r["config"]["applies"]) for r in rows}
    assert met["decode_floor"] == (1, True)  # 1.25 <= 1.3
    assert met["inflation"] == (0, False)  # decode 6x: missed, but a one-core client is not held to it
    assert met["decode_inflation"][0] == 0 and met["request_inflation"][0] == 1  # 2.5 / 2.0 <= 1.5
    assert all(r["config"]["machine"] == "test box" for r in rows)
