"""`bench load` end to end at a tiny load: a real cloudbaking-server, its three phases, the targets' rows."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from bench.load import BENCH, PHASES, TARGETS, LoadConfig
from bench.runner import execute
from gicore.results import read_rows
from tests.helpers.cloud import write_scenes


@pytest.mark.slow
def test_load_bench_writes_every_phase_and_target(tmp_path: Path) -> None:
    spec = write_scenes(tmp_path / "scenes") / "ball_static.json"
    small = {"hit_clients": 2, "period_ms": 50.0, "misses": 12, "idle": 40, "max_connections": 16}
    small |= {"settle_s": 0.3, "reference_s": 0.3}
    cfg = replace(LoadConfig.quick(), scenes=(str(spec),), **small)
    files = execute(BENCH, cfg, tmp_path / "out")
    assert {p.name for p in files} == {"load.csv", "load.provenance.json", "load.md"}
    rows = read_rows(tmp_path / "out" / "load.csv")
    for phase in PHASES:
        mine = {(r["metric"], r["stat"]) for r in rows if r["config"].get("phase") == phase}
        assert {("hit_latency", s) for s in ("median", "p99", "max", "n")} | {("errors", "value")} <= mine, phase
    assert {r["config"]["status"] for r in rows if r["metric"] == "miss_status"} <= {200, 503}
    idle = {
        r["config"]["counter"]: r["value"]
        for r in rows
        if r["metric"] == "connections" and r["config"]["phase"] == "idle"
    }
    assert set(idle) == {"accepted", "drained", "timed_out", "refused"}, idle
    assert idle["accepted"] > idle["drained"] > 0, idle  # the hit clients' connections were accepted, not drained
    targets = [r for r in rows if r["stat"] == "target_met"]
    assert [r["config"]["target"] for r in targets] == [t.label for t, _ in TARGETS]
    assert {r["value"] for r in targets} <= {0, 1}
    assert "met" in (tmp_path / "out" / "load.md").read_text()
    assert json.loads((tmp_path / "out" / "load.provenance.json").read_text())["machine"]
    assert not any(p.name.startswith("load_store_") for p in (tmp_path / "out").iterdir())  # the store is gone
