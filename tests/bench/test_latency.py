"""`bench latency` (Table 1): the whole bench end to end at 64² (server, proxy, both clients as processes),
the link-model crossover against closed forms, the core pinning plan, and its option checks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bench import latency
from bench.latency import CloudCost, LatencyConfig, pinning, sweep_link
from bench.runner import execute
from gicore.results import read_rows
from tests.helpers.cloud import passthrough_model, write_scenes


@pytest.mark.slow
def test_bench_latency_end_to_end(tmp_path: Path) -> None:
    scene = write_scenes(tmp_path / "scenes") / "ball_moving.json"
    cfg = LatencyConfig(scenes=(str(scene),), profiles=("rtt60",), resolution=64, frames=12, every=2, spp=4, gt_every=4,
                        model=passthrough_model(tmp_path / "model"), sweep_max_rtt_ms=200.0)  # fmt: skip
    out = tmp_path / "out"
    files = execute(latency.BENCH, cfg, out, seed=0)
    rows = read_rows(out / "latency.csv")

    def stats(system: str, **config) -> set[str]:
        return {
            r["metric"]
            for r in rows
            if r["system"] == system
            and r["stat"] == "median"
            and all(r["config"].get(k) == v for k, v in config.items())
        }

    assert stats("gigan", profile="none") >= {"gi_render", "inference", "warp", "blend", "total", "di"}
    common = {
        "transmission",
        "request",
        "transfer",
        "lookup",
        "server_other",
        "decode",
        "warp",
        "blend",
        "total",
        "pickup",
    }
    assert stats("cloud_baking", profile="rtt60", cache="hit") >= common | {"read"}
    assert stats("cloud_baking", profile="rtt60", cache="miss") >= common | {"render", "denoise", "encode"}

    def value(metric: str, stat: str = "median", system: str = "cloud_baking", **config) -> float:
        [v] = [
            r["value"]
            for r in rows
            if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and r["config"].items() >= config.items()
        ]
        return v

    for cache in ("hit", "miss"):  # the profile's 60 ms round trip is in every request's transmission
        assert value("transmission", "median", profile="rtt60", cache=cache) >= 59.0
        ratio = value("total_ratio", system="cloud_baking/gigan", profile="rtt60", cache=cache)
        assert ratio == pytest.approx(
            value("total", profile="rtt60", cache=cache) / value("total", system="gigan", profile="none")
        )
        assert value("crossover_rtt", "model", system="cloud_baking/gigan", cache=cache) >= 0
    assert value("total", profile="rtt60", cache="miss") > value("total", profile="rtt60", cache="hit")
    # the prebaked store answered every request of its run; the cold one missed its first (later ones hit
    # only where this run had baked a map within the tolerance already)
    prebaked, cold = (
        [r for r in _csv(out / "latency_runs" / f"cloud_rtt60_{s}" / "requests.csv") if r["status"] == "ok"]
        for s in ("prebaked", "cold")
    )
    assert prebaked and {r["hit"] for r in prebaked} == {"1"} and cold[0]["hit"] == "0"
    assert value("failed_requests", "value", profile="rtt60", store="cold") == 0
    ssim = [r for r in rows if r["metric"] == "ssim" and r["stat"] == "frame"]
    assert {(r["system"], r["config"]["store"]) for r in ssim} == {
        ("gigan", "none"),
        ("cloud_baking", "prebaked"),
        ("cloud_baking", "cold"),
    }
    assert {r["config"]["frame"] for r in ssim} == {0, 4, 8} and all(0 < r["value"] <= 1 for r in ssim)

    provenance = json.loads((out / "latency.provenance.json").read_text())
    assert provenance["settings"]["pinning"]["method"] in ("taskset -c", "none")
    table = (out / "latency_table.md").read_text()
    assert (
        "### profile `rtt60` (RTT 60 ms)" in table
        and "**total (interaction latency)**" in table
        and "crossover" in table
    )
    assert {p.name for p in files} >= {
        "latency.csv",
        "latency_table.md",
        "latency_stages.png",
        "latency_ratio_rtt.png",
        "latency_ssim.png",
    }


def _csv(path: Path) -> list[dict[str, str]]:
    import csv

    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_crossover_matches_the_closed_form() -> None:
    """Unlimited rate: the network costs exactly the RTT, so GIGAN wins beyond (its total - cloud's local
    part); at 5 Mbit/s the response's serialization (bytes * 8 / rate) is added to cloud's side."""
    cost = CloudCost(local_ms=10.0, server_ms=5.0, bytes_up=500, bytes_down=100_000)
    assert cost.network_ms(sweep_link(80.0, None)) == pytest.approx(80.0, abs=1e-6)
    assert cost.crossover_rtt_ms(40.0, None) == pytest.approx(30.0, abs=0.1)
    assert cost.crossover_rtt_ms(5.0, None) == 0.0  # GIGAN faster at any RTT
    serialization_ms = (500 + 100_000) * 8 / 5e6 * 1e3
    assert cost.network_ms(sweep_link(80.0, 5.0)) == pytest.approx(80.0 + serialization_ms, abs=0.01)
    assert cost.crossover_rtt_ms(400.0, 5.0) == pytest.approx(400.0 - 10.0 - serialization_ms, abs=0.1)


def test_link_model_of_a_profile() -> None:
    """The wan profile: 130 ms RTT and 5 Mbit/s each way."""
    from network_sim.profiles import get

    cost = CloudCost(local_ms=0.0, server_ms=50.0, bytes_up=1000, bytes_down=62_500)
    assert cost.total_ms(get("wan").link(), starts=5) == pytest.approx(130.0 + (1000 + 62_500) * 8 / 5e6 * 1e3, abs=0.1)


def test_pinning_plan(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(latency.shutil, "which", lambda name: "/usr/bin/taskset")
    monkeypatch.setattr(latency.os, "sched_getaffinity", lambda pid: {0, 1})
    assert pinning(True) == {"method": "taskset -c", "cores": [0, 1], "server": [0], "proxy": [0], "client": [1]}
    assert latency._prefix(pinning(True), "client") == ["taskset", "-c", "1"]
    monkeypatch.setattr(latency.os, "sched_getaffinity", lambda pid: set(range(8)))
    plan = pinning(True)
    assert (plan["proxy"], plan["server"], plan["client"]) == ([0], [1, 2, 3], [4, 5, 6, 7])
    assert pinning(False)["method"] == "none" and latency._prefix(pinning(False), "server") == []
    monkeypatch.setattr(latency.shutil, "which", lambda name: None)
    assert pinning(True) == {
        "method": "none",
        "reason": "taskset (util-linux) is not installed",
        "cores": list(range(8)),
    }


def test_unknown_profile_is_a_user_error(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "bench", "latency", "--profiles", "lan,moon", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    [line] = [x for x in proc.stderr.splitlines() if x.startswith("error:")]
    assert "--profiles 'moon'" in line and "wan" in line
