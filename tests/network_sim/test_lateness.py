"""The proxy reports its own fidelity: how late it wrote chunks after the release time the link model gave them
(``network-sim proxy --lateness``, :mod:`network_sim.chunklog`), and a verdict on whether the run kept time."""

from __future__ import annotations

import math
import os
import random
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from gicore.error_policy import UserError
from network_sim import endpoint
from network_sim.chunklog import (
    LATENESS_PARTS,
    LatenessSummary,
    lateness,
    lateness_limit_ms,
    read_lateness,
    reliable,
)
from network_sim.link import DOWN, UP
from network_sim.process import Running, network_sim, proxy

TIMEOUT = 60.0
#: A percentile the summary reports is never below the true one and at most this much above it (its bin's width).
BIN_WIDTH = 10 ** (1 / 100)


@pytest.fixture(scope="module")
def upstream() -> Iterator[tuple[str, int]]:
    with network_sim("server") as running:
        yield running.addr


def test_the_limit_is_a_tenth_of_the_rtt_and_at_least_a_millisecond() -> None:
    assert [lateness_limit_ms(rtt) for rtt in (0.0, 5.0, 10.0, 40.0, 260.0)] == [1.0, 1.0, 1.0, 4.0, 26.0]
    part = {"chunks": 1, "dropped": 0, "p50_ms": 1.0, "p99_ms": 4.0, "max_ms": 4.0}
    summary = {"up": part, "down": part, "all": part}
    assert reliable(summary, 40.0) and not reliable(summary, 39.0)
    nothing = {"chunks": 0, "dropped": 3, "p50_ms": None, "p99_ms": None, "max_ms": None}
    assert reliable({"up": nothing, "down": nothing, "all": nothing}, 0.0)  # no chunk written: never late


def test_summary_percentiles_bound_the_true_ones_from_above_within_a_bin() -> None:
    """Log-normal lateness (median 0.2 ms, a tail to tens of ms) plus early and dropped chunks: every reported
    percentile is at or above the nearest-rank one and within one bin, the maximum exact, and the parts add up."""
    rng = random.Random(3)
    drawn = {UP: [rng.lognormvariate(math.log(2e-4), 1.5) for _ in range(5000)], DOWN: [-5e-7, 3e-7, 0.25]}
    summary = LatenessSummary()
    for direction, values in drawn.items():
        for v in values:
            summary.add(direction, v)
    summary.add(DOWN, None)
    out = summary.summary()
    for name, values in (*drawn.items(), ("all", drawn[UP] + drawn[DOWN])):
        part = out[name]
        assert part["chunks"] == len(values) and part["max_ms"] == max(values) * 1e3
        for q in (50, 99):
            true_ms = float(np.percentile(values, q, method="inverted_cdf")) * 1e3
            assert true_ms <= part[f"p{q}_ms"] <= max(true_ms * BIN_WIDTH, 1e-3) + 1e-12, (name, q)
    assert (out[UP]["dropped"], out[DOWN]["dropped"], out["all"]["dropped"]) == (0, 1, 1)
    empty = LatenessSummary().summary()["all"]
    assert empty == {"chunks": 0, "dropped": 0, "p50_ms": None, "p99_ms": None, "max_ms": None}


def _download_through(p: Running, stop_s: float) -> int:
    """Download 1 MB through proxy ``p`` (8 Mbit/s: about a second of link time); once the first bytes are in, the
    proxy is stopped (SIGSTOP) for ``stop_s`` while the rest is due, then continued. Returns the bytes received."""
    with endpoint.connect(p.addr, b"G", TIMEOUT) as sock:
        sock.sendall(endpoint.SOURCE_REQUEST.pack(1_000_000, 7))
        received = len(sock.recv(65536))
        if stop_s:
            os.kill(p.proc.pid, signal.SIGSTOP)
            try:
                time.sleep(stop_s)
            finally:
                os.kill(p.proc.pid, signal.SIGCONT)
        while data := sock.recv(65536):
            received += len(data)
    return received


def test_a_stopped_proxy_reports_later_chunks_than_an_undisturbed_one(
    upstream: tuple[str, int], tmp_path: Path
) -> None:
    """Two runs of the same download, one with the proxy stopped 200 ms while chunks are due: each writes a summary
    that counts every chunk of its log and equals what :func:`lateness` computes from that log; the stopped run's
    p99 is the larger and fails the verdict."""
    reports = []
    for stop_s in (0.0, 0.2):
        log, summary = tmp_path / f"log{stop_s}.csv", tmp_path / f"late{stop_s}.json"
        args = ("--rate-mbit", "8", "--delay-ms", "20", "--log", str(log), "--lateness", str(summary))
        with proxy(upstream, *args) as p:
            assert _download_through(p, stop_s) == 1_000_000
        report = read_lateness(summary)
        rows = log.read_text().splitlines()[1:]
        assert report["all"]["chunks"] == len(rows) > 50  # every chunk was written: none dropped
        assert report["all"]["chunks"] == report[UP]["chunks"] + report[DOWN]["chunks"]
        assert {k: report[k] for k in LATENESS_PARTS} == lateness(log)
        for part in LATENESS_PARTS:
            assert report[part]["p50_ms"] <= report[part]["p99_ms"] <= report[part]["max_ms"]
        assert (report["rtt_ms"], report["limit_ms"]) == (40.0, 4.0)
        assert report["reliable"] == reliable(report, 40.0)
        reports.append(report)
    undisturbed, stopped = reports
    assert stopped["all"]["p99_ms"] > undisturbed["all"]["p99_ms"], (undisturbed["all"], stopped["all"])
    assert not stopped["reliable"]


def test_a_summary_is_written_without_a_log_and_replaces_an_old_one(upstream: tuple[str, int], tmp_path: Path) -> None:
    """The summary needs no per-chunk log; one left by an earlier run is gone while the proxy runs (a killed proxy
    leaves none, rather than an old one), and the new one counts this run's chunks."""
    summary = tmp_path / "late.json"
    summary.write_text('{"stale": true}')
    with proxy(upstream, "--lateness", str(summary)) as p:
        assert not summary.exists()
        assert endpoint.echo(p.addr, b"x" * 10_000, TIMEOUT) == b"x" * 10_000
    report = read_lateness(summary)
    assert report[UP]["chunks"] >= 1 and report[DOWN]["chunks"] >= 1 and report["rtt_ms"] == 0.0


def test_reading_a_missing_or_foreign_summary_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no lateness summary at .*stop it so"):
        read_lateness(tmp_path / "none.json")
    (tmp_path / "other.json").write_text('{"up": 1}')
    with pytest.raises(UserError, match="is not a proxy's"):
        read_lateness(tmp_path / "other.json")
    (tmp_path / "cut.json").write_text('{"up": {')
    with pytest.raises(UserError, match="cannot be read"):
        read_lateness(tmp_path / "cut.json")
