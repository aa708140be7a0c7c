"""`bench service` end to end on a tiny run: a real cloudbaking-server, misses, hits and a concurrent load."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.runner import execute
from bench.server_bench import BENCH, ServiceConfig
from gicore.results import read_rows
from tests.helpers.cloud import write_scenes

METRICS = ("miss_e2e", "miss_server", "hit_server", "hit_e2e", "load_latency", "load_throughput", "load_errors")


@pytest.mark.slow
def test_service_bench_measures_every_metric_against_a_real_server(tmp_path: Path) -> None:
    spec = write_scenes(tmp_path / "scenes") / "ball_static.json"
    cfg = ServiceConfig(
        scenes=(str(spec),),
        resolution=64,
        spp=4,
        views=2,
        sequential=5,
        concurrency=4,
        per_client=3,
        read_timeout_s=60.0,
    )
    files = execute(BENCH, cfg, tmp_path / "out")
    assert {p.name for p in files} >= {
        "service.csv",
        "service.provenance.json",
        "service.md",
        "service.png",
        "service.svg",
    }
    assert "server lookup + read (n=5)" in (tmp_path / "out" / "service.svg").read_text()  # a declared series
    rows = read_rows(tmp_path / "out" / "service.csv")
    assert set(METRICS) <= {r["metric"] for r in rows}

    def value(metric: str, stat: str = "value", **config) -> float:
        return next(
            r["value"]
            for r in rows
            if r["metric"] == metric and r["stat"] == stat and config.items() <= r["config"].items()
        )

    assert value("load_errors") == 0
    assert value("load_latency", "n") == 12 and value("hit_e2e", "n") == 5
    assert 0 < value("load_throughput") < 1e5
    assert (
        0
        < value("hit_server", "median", part="lookup_read")
        <= value("hit_server", "median", part="total")
        < value("hit_e2e", "median")
    )  # the server's part of a hit, within the whole round trip
    assert (
        value("miss_server", "first", part="render") > 0 and value("miss_server", "n", part="render") == 1
    )  # the second view missed too
    targets = [r for r in rows if r["stat"] == "target_met"]
    assert len(targets) == 4 and {r["value"] for r in targets} <= {0, 1}
    assert next(r for r in targets if r["metric"] == "load_errors")["value"] == 1
    assert not any(
        p.name.startswith("service_store_") for p in (tmp_path / "out").iterdir()
    )  # the temporary store is gone
