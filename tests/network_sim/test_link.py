"""The virtual-clock link model, traces and profiles of network_sim (pure Python, no processes)."""

from __future__ import annotations

import math
import statistics
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gicore.error_policy import UserError
from network_sim.link import DOWN, UP, DirectionConfig, Link, LinkConfig, standardized
from network_sim.profiles import get as get_profile
from network_sim.profiles import profiles
from network_sim.trace import Trace, _parse_checking, _parse_clean, parse_lines
from network_sim.tracegen import MODELS, generate, shipped_path, trace_stats


def _link(**up: object) -> Link:
    return Link(LinkConfig(up=DirectionConfig(**up)))  # type: ignore[arg-type]


def test_rate_serializes_back_to_back_chunks_exactly() -> None:
    stream = _link(rate_mbit=8.0, delay_ms=10.0).stream(0, UP)  # 1 MB/s
    releases = [stream.send(10_000, 0.0).release for _ in range(5)]
    assert releases == pytest.approx([0.010 + 0.010 * (i + 1) for i in range(5)], abs=1e-12)


def test_idle_rate_link_starts_at_arrival() -> None:
    stream = _link(rate_mbit=8.0).stream(0, UP)
    assert stream.send(1000, 0.0).finish == pytest.approx(0.001)
    assert stream.send(1000, 5.0).finish == pytest.approx(5.001)  # the link was idle: no credit saved


def test_trace_opportunities_wrap_and_waste() -> None:
    # opportunities at 1, 1, 3 ms, period 3 ms (then 4, 4, 6, 7, 7, 9 ...)
    trace = Trace.from_ms("t", parse_lines("t", ["1", "1", "3"]))
    assert trace.mean_mbit == pytest.approx(3 * 1500 * 8 / 0.003 / 1e6)
    link = Link(LinkConfig(down=DirectionConfig(trace=trace)))
    stream = link.stream(0, DOWN)
    assert stream.send(3000, 0.0).finish == pytest.approx(0.001)  # both opportunities at 1 ms
    assert stream.send(1500, 0.0).finish == pytest.approx(0.003)
    assert stream.send(4500, 0.0).finish == pytest.approx(0.006)  # 4, 4, 6 ms after the wrap
    # arriving at 6.5 ms: the opportunities at 7 ms serve it; the one at 6 ms has passed
    assert stream.send(100, 0.0065).finish == pytest.approx(0.007)
    # an idle link wastes its opportunities: nothing is saved up between 7 and 20 ms
    assert stream.send(4500, 0.020).finish == pytest.approx(0.022)
    assert trace.capacity_bytes(0.0, 0.009) == 9 * 1500 and trace.capacity_bytes(0.0035, 0.007) == 5 * 1500


def test_a_one_line_trace_is_12_mbit() -> None:
    trace = Trace.from_ms("one", [1])
    assert trace.mean_mbit == pytest.approx(12.0)
    stream = Link(LinkConfig(up=DirectionConfig(trace=trace))).stream(0, UP)
    last = [stream.send(15_000, 0.0).finish for _ in range(100)][-1]
    assert last == pytest.approx(1.0)  # 1.5 MB in 1000 opportunities of 1500 bytes


@pytest.mark.parametrize(
    ("lines", "line", "what"),
    [
        (["10", "", "30"], 2, "empty"),
        (["10", "2x0"], 2, "not a whole number"),
        (["10", "5"], 2, "smaller than the line before"),
        (["-3"], 1, "negative"),
        (["0", "0"], 2, "lasts no time"),
    ],
)
def test_malformed_trace_names_file_and_line(lines: list[str], line: int, what: str) -> None:
    with pytest.raises(UserError) as err:
        parse_lines("bad.trace", lines)
    assert f"bad.trace line {line}" in str(err.value) and what in str(err.value)


def test_the_quick_parse_of_a_clean_trace_is_the_checking_parse() -> None:
    """Clean traces take a one-pass parse, anything else the line-by-line one; both agree where both run."""
    for model in MODELS.values():
        lines = shipped_path(model.file).read_text().splitlines()
        assert _parse_clean(lines) == _parse_checking(model.file, lines)
    assert _parse_checking("t", [" 1", "2\r"]) == [1, 2]  # whitespace is the checking parse's to allow
    for lines in (["1", " 2"], ["2", "1"], ["0"], ["1", str(10**9 + 1)], ["1", "１"], []):
        assert _parse_clean(lines) is None


def test_empty_trace_file_is_rejected(tmp_path: Path) -> None:
    (tmp_path / "e.txt").write_text("")
    with pytest.raises(UserError, match="has no timestamps"):
        Trace.load(tmp_path / "e.txt")


def test_queue_bound_gives_backpressure_not_loss() -> None:
    link = _link(rate_mbit=8.0, queue_bytes=4000)  # 1 MB/s, 4 kB queue
    stream = link.stream(0, UP)
    chunks = [stream.send(1000, 0.0) for _ in range(10)]
    assert [c.admitted for c in chunks[:4]] == [0.0] * 4  # the queue holds four
    # each later chunk waits until the queue has drained 1000 bytes
    assert [c.admitted for c in chunks[4:]] == pytest.approx([0.001 * (i + 1) for i in range(6)])
    assert sum(c.nbytes for c in chunks) == 10_000 and chunks[-1].finish == pytest.approx(0.010)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 2), st.integers(1, 16384), st.floats(0, 0.02)), min_size=1, max_size=60),
    st.sampled_from([None, 1.0, 50.0]),
    st.integers(1500, 60_000),
    st.floats(0, 20),
    st.sampled_from(["normal", "pareto", "uniform"]),
    st.floats(0, 0.3),
)
def test_model_invariants(
    offers: list[tuple[int, int, float]], rate: float | None, queue: int, jitter: float, dist: str, loss: float
) -> None:
    """Whatever the traffic: streams stay in order, nothing leaves before arrival + delay, the shared queue
    never holds more than its bound, and bytes are never dropped (every chunk gets a release time)."""
    config = DirectionConfig(
        delay_ms=5.0, jitter_ms=jitter, jitter_dist=dist, rate_mbit=rate, queue_bytes=queue, loss=loss
    )  # type: ignore[arg-type]
    link = Link(LinkConfig(up=config))
    t, chunks = 0.0, []
    for conn, size, gap in offers:
        t += gap
        chunks.append(link.stream(conn, UP).send(min(size, link.directions[UP].max_chunk), t))
    for conn in range(3):
        mine = [c for c in chunks if c.conn == conn]
        assert all(a.release <= b.release for a, b in zip(mine, mine[1:]))
    for c in chunks:
        assert c.arrival <= c.admitted <= c.finish <= c.ready <= c.release
        if jitter == 0:
            assert c.release >= c.ready + 0.005 - 1e-12
        if rate is not None:  # bytes not yet serialized when c is admitted (FIFO, fluid) never exceed the bound
            bytes_per_s = rate * 1e6 / 8
            queued = sum(min(o.nbytes, max(0.0, o.finish - c.admitted) * bytes_per_s) for o in chunks if o.seq <= c.seq)
            assert queued <= queue + 1e-6


def test_zero_rate_and_total_loss_never_release_and_stop_the_sender() -> None:
    dead = _link(rate_mbit=0.0, queue_bytes=3000).stream(0, UP)
    assert [math.isinf(dead.send(1500, 0.0).release) for _ in range(2)] == [True, True]
    assert math.isinf(dead.send(1500, 0.0).admitted)  # queue full forever: the sender is never read again
    lossy = Link(LinkConfig(up=DirectionConfig(loss=1.0), window_bytes=4000)).stream(0, UP)
    assert math.isinf(lossy.send(4000, 0.0).release)
    assert math.isinf(lossy.window_open_at(1, 0.0))  # window full of bytes never acknowledged


def test_a_blocked_connection_does_not_block_the_shared_link() -> None:
    link = Link(LinkConfig(up=DirectionConfig(rate_mbit=8.0, loss=1.0), window_bytes=2000))
    blocked = link.stream(0, UP)
    blocked.send(2000, 0.0)
    assert math.isinf(blocked.window_open_at(1000, 0.001))
    other = Link(LinkConfig(up=DirectionConfig(rate_mbit=8.0))).stream(1, UP)
    assert other.send(1000, 0.001).finish == pytest.approx(0.002)


def test_loss_draws_follow_stream_offsets_not_chunking() -> None:
    config = LinkConfig(up=DirectionConfig(loss=0.2), seed=7)
    whole, pieces = Link(config).stream(0, UP), Link(config).stream(0, UP)
    lost_whole = sum(whole.send(16_384, 0.0).lost for _ in range(40))
    lost_pieces = sum(pieces.send(1024, 0.0).lost for _ in range(640))
    # same segments, same draws; a segment split over two chunks counts in both
    assert lost_whole > 0 and lost_pieces >= lost_whole


def test_loss_share_and_retransmission_delay() -> None:
    config = LinkConfig(up=DirectionConfig(delay_ms=30.0, loss=0.1), down=DirectionConfig(delay_ms=30.0))
    link = Link(config)
    assert config.rto_s == pytest.approx(0.2)  # max(200 ms, 2 * 60 ms)
    n, delayed = 4000, []
    for conn in range(n):  # one single-segment message per connection, like the self-test's probes
        chunk = link.stream(conn, UP).send(100, conn * 1.0)
        delayed.append(chunk.release - chunk.arrival - 0.030)
    share = sum(d > 0.1 for d in delayed) / n
    assert abs(share - 0.1) < 3 * math.sqrt(0.09 / n)
    paid = [d for d in delayed if d > 0.1]
    assert statistics.median(paid) == pytest.approx(0.2, abs=1e-9)
    assert all(d / 0.2 == pytest.approx(round(d / 0.2), abs=1e-9) for d in paid)  # one RTO per lost transmission
    assert LinkConfig(up=DirectionConfig(delay_ms=150), down=DirectionConfig(delay_ms=150)).rto_s == pytest.approx(0.6)


@pytest.mark.parametrize("dist", ["normal", "pareto", "uniform"])
@pytest.mark.parametrize("gap_s", [0.0005, 0.01])
def test_jitter_keeps_the_configured_spread_and_never_reorders(dist: str, gap_s: float) -> None:
    """Sparse probes and back-to-back chunks alike: the delay's mean and std are the configured ones
    (within 8 % for this run length; the FIFO max inflates the Pareto tail a little), and releases never
    go backwards."""
    link = Link(LinkConfig(up=DirectionConfig(delay_ms=50.0, jitter_ms=5.0, jitter_dist=dist), seed=3))
    stream = link.stream(0, UP)
    delays, last = [], -1.0
    for i in range(int(60 / gap_s) if gap_s > 0.001 else 60_000):
        chunk = stream.send(100, i * gap_s)
        assert chunk.release >= last
        last = chunk.release
        delays.append((chunk.release - chunk.arrival) * 1e3)
    assert statistics.fmean(delays) == pytest.approx(50.0, abs=0.6)
    assert statistics.pstdev(delays) == pytest.approx(5.0, rel=0.08)


def test_standardized_distributions_have_unit_spread() -> None:
    import random

    rng = random.Random(0)
    zs = [rng.gauss(0, 1) for _ in range(200_000)]
    for dist in ("normal", "pareto", "uniform"):
        xs = [standardized(dist, z) for z in zs]
        assert statistics.fmean(xs) == pytest.approx(0.0, abs=0.01) and statistics.pstdev(xs) == pytest.approx(
            1.0, abs=0.01
        )


def test_same_seed_same_link_other_seed_other_draws() -> None:
    def releases(seed: int) -> list[float]:
        link = Link(LinkConfig(up=DirectionConfig(delay_ms=20, jitter_ms=5, loss=0.1, rate_mbit=10), seed=seed))
        return [link.stream(i % 3, UP).send(5000, i * 0.003).release for i in range(300)]

    assert releases(1) == releases(1) and releases(1) != releases(2)


def test_message_helper_and_window_limit() -> None:
    link = Link(LinkConfig(up=DirectionConfig(delay_ms=25.0, rate_mbit=8.0)))
    assert link.message(0, UP, 100_000, 0.0) == pytest.approx(0.025 + 0.1)
    # a window of 64 kB over a 50 ms RTT caps an unlimited link at ~1.3 MB/s, as TCP would be
    slow = Link(LinkConfig(up=DirectionConfig(delay_ms=25.0), down=DirectionConfig(delay_ms=25.0), window_bytes=65_536))
    assert slow.message(0, UP, 1_310_720, 0.0) == pytest.approx(19 * 0.05 + 0.025, abs=1e-9)


@pytest.mark.parametrize(
    "bad",
    [
        dict(delay_ms=-1.0),
        dict(jitter_ms=math.nan),
        dict(loss=1.5),
        dict(rate_mbit=-2.0),
        dict(queue_bytes=100),
        dict(jitter_dist="cauchy"),
    ],
)
def test_invalid_direction_configs_are_rejected(bad: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        DirectionConfig(**bad)  # type: ignore[arg-type]


def test_chunks_larger_than_the_direction_takes_are_rejected() -> None:
    stream = _link(rate_mbit=1.0, queue_bytes=2000).stream(0, UP)
    with pytest.raises(ValueError, match="takes 1..2000"):
        stream.send(2001, 0.0)


def test_shipped_traces_are_their_generators_output_and_match_the_recorded_statistics() -> None:
    for model in MODELS.values():
        shipped = shipped_path(model.file).read_text().split()
        assert [int(x) for x in shipped] == generate(model)
        stats = trace_stats(Trace.load(shipped_path(model.file)))
        recorded = dict(part.split(" ", 1) for part in model.source.split(": ", 1)[1].split(", "))
        assert stats["mean_mbit"] == pytest.approx(model.mean_mbit, rel=0.01)
        assert stats["cv100"] == pytest.approx(float(recorded["cv100"]), rel=0.1)
        assert stats["ac100"] == pytest.approx(float(recorded["ac100"]), abs=0.03)
        assert stats["empty100"] == pytest.approx(float(recorded["empty100"]), abs=0.01)


def test_profiles_cover_the_issue_and_cite_sources() -> None:
    table = profiles()
    assert {"loopback", "lan", "wifi", "wan", "lte", "3g", "rtt60", "rtt100", "rtt120", "rtt250"} <= set(table)
    assert table["wan"].link().rtt_s == pytest.approx(0.130) and table["wan"].down.rate_mbit == 5.0
    assert table["3g"].link().rtt_s == pytest.approx(0.300) and table["3g"].down.rate_mbit == 0.7
    assert [table[f"rtt{r}"].link().rtt_s for r in (60, 100, 120, 250)] == pytest.approx([0.06, 0.1, 0.12, 0.25])
    lte = table["lte"]
    assert lte.down.trace is not None and 5.0 <= lte.down.trace.mean_mbit <= 17.0
    assert all(p.source for p in table.values())
    with pytest.raises(UserError, match="not a known profile"):
        get_profile("5g")


def test_importing_network_sim_pulls_in_no_other_project_package() -> None:
    code = (
        "import sys, network_sim, network_sim.cli, network_sim.proxy, network_sim.selftest, "
        "network_sim.profiles, network_sim.endpoint;"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('mitsuba', 'torch', 'fastapi', 'baseline_cloudbaking', 'gigan_local', 'bench', 'onnxruntime', 'drjit'));"
        "print(','.join(bad))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    ).stdout.strip()
    assert out == ""
