"""What a ``cloudbaking-client`` run's files give back (:class:`baseline_cloudbaking.client_run.RunMetrics`):
perceived latency by cache state with never-served frames as endless, the in-tolerance share, SSIM, request counts
and bytes, and the stage samples of the shown requests. (The client writing these files: test_client.py.)"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from baseline_cloudbaking.client_run import PERCEIVED_COLUMNS, REQUEST_COLUMNS, REQUEST_STAGES, RunMetrics
from gicore.frame_rows import write_rows


def frame(n: int, ssim: float | str, in_tolerance: int, perceived_ms: float | str, perceived_map: int | str) -> dict:
    row = dict.fromkeys(PERCEIVED_COLUMNS, "") | {"frame": n, "ssim": ssim, "in_tolerance": in_tolerance}
    return row | {"perceived_ms": perceived_ms, "perceived_map": perceived_map}


def request(n: int, hit: int, status: str = "ok", down: int | str = 1000, total: float | str = "") -> dict:
    row = dict.fromkeys(REQUEST_COLUMNS, "") | {"frame": n, "hit": hit, "status": status, "bytes_up": 300}
    return row | {"bytes_down": down, "latency_ms": 40.0 if status == "ok" else "", "total_ms": total}


def write_run(folder: Path, frames: list[dict], requests: list[dict]) -> Path:
    write_rows(frames, folder / "frames.csv")
    write_rows(requests, folder / "requests.csv")
    return folder


def test_a_runs_metrics_count_never_served_frames_as_endless(tmp_path: Path) -> None:
    frames = [
        frame(0, 0.9, 1, 30.0, 0),
        frame(1, "", 0, "", ""),  # never served
        frame(2, 0.8, 0, 90.0, 3),
        frame(3, "", 1, 20.0, 3),
    ]
    requests = [request(0, 1), request(3, 0, down=2000), request(5, 0, status="timeout", down="")]
    m = RunMetrics.read(write_run(tmp_path, frames, requests))
    assert m.perceived == {"all": [30.0, math.inf, 90.0, 20.0], "hit": [30.0], "miss": [90.0, 20.0]}
    assert (m.censored, m.in_tolerance, m.ssim) == (1, 0.5, {0: 0.9, 2: 0.8})
    assert m.mean_ssim == pytest.approx(0.85)
    assert (m.requests, m.failed_requests, m.bytes_up, m.bytes_down) == (3, 1, 900, 3000)
    assert m.request_latency == [40.0, 40.0] and m.stages == {}  # no request's map was shown
    # order statistics: the median of all frames is a measured wait; the p95, the never-served frame's endless one
    assert m.quantiles() == {"median": 30.0, "p95": math.inf}
    assert m.quantiles("miss") == {"median": 20.0, "p95": 90.0}


def test_the_stage_samples_are_the_shown_requests_by_cache_state(tmp_path: Path) -> None:
    """Each shown request's stages (``warp``: the bind and the per-frame warp), its total, pickup and bytes, under
    its cache state; stages it did not go through (a hit's render) and requests never shown are left out."""
    stages = {f"{s}_ms": 1.0 for s in REQUEST_STAGES if s not in ("render", "denoise", "encode", "warp")}
    shown = request(0, 1, total=20.0) | stages | {"bind_ms": 1.0, "warp_ms": 2.0, "pickup_ms": 4.0}
    shown["server_ms"] = 3.0
    late = request(3, 0) | stages  # answered, but no frame bound its map
    m = RunMetrics.read(write_run(tmp_path, [frame(0, "", 1, 10.0, 0)], [shown, late]))
    assert list(m.stages) == ["hit"]
    hit = m.stages["hit"]
    assert "render" not in hit and hit["warp"] == [3.0] and hit["di"] == [1.0]  # bind 1 + warp 2
    assert (hit["total"], hit["pickup"], hit["server"]) == ([20.0], [4.0], [3.0])
    assert (hit["bytes_up"], hit["bytes_down"]) == ([300.0], [1000.0])
