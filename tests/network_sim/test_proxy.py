"""The network_sim proxy as a real process on 127.0.0.1 (ephemeral ports) in front of the endpoint server.

Tolerances allow for a loaded 2-core machine; `network-sim selftest` holds the proxy to tighter targets on a
quiet one. Every socket and process wait is bounded.
"""

from __future__ import annotations

import csv
import hashlib
import os
import signal
import socket
import statistics
import struct
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from network_sim import endpoint
from network_sim.cli import link_config
from network_sim.link import Link
from network_sim.process import Running, network_sim
from network_sim.profiles import profiles
from network_sim.proxy import REFUSAL_REPORT_S

TIMEOUT = 30.0


@pytest.fixture(scope="module")
def server() -> Iterator[Running]:
    with network_sim("server") as running:
        yield running


def _proxy(server: Running, *args: str) -> Running:
    host, port = server.addr
    running = network_sim("proxy", "--upstream", f"{host}:{port}", *args)
    running.readline(TIMEOUT)  # the clock-origin line
    return running


def _payload(nbytes: int, seed: int) -> bytes:
    return b"".join(endpoint.blocks(nbytes, seed))


#: Bytes echoed through each profile: short payloads where the link is slow.
_SIZES = {"3g": 20_000, "lte": 200_000, "lte-fast": 200_000, "wan": 100_000}


@pytest.mark.parametrize("name", list(profiles()))
def test_every_profile_is_byte_exact(server: Running, name: str) -> None:
    payload = _payload(_SIZES.get(name, 1_000_000), seed=len(name))
    with _proxy(server, "--profile", name) as proxy:
        echoed = endpoint.echo(proxy.addr, payload, TIMEOUT)
    assert hashlib.sha256(echoed).digest() == hashlib.sha256(payload).digest()


def test_connection_cap_closes_one_more_and_reports_it_once(server: Running) -> None:
    """--max-connections 3: three held connections work, more are closed (no byte, EOF), a freed slot takes
    the next; 200 refusals make one stderr line per report interval (REFUSAL_REPORT_S), not 200."""
    with _proxy(server, "--max-connections", "3") as proxy:
        held = [socket.create_connection(proxy.addr, timeout=TIMEOUT) for _ in range(3)]
        try:
            for sock in held:
                sock.sendall(b"E")  # echo mode: the proxy forwards, the endpoint echoes
            first = time.monotonic()
            for _ in range(200):
                with socket.create_connection(proxy.addr, timeout=TIMEOUT) as extra:
                    assert extra.recv(1) == b""
            held[0].sendall(b"ping")
            assert held[0].recv(4) == b"ping"
            held.pop().close()
            assert _echo_once_a_slot_is_free(proxy.addr, b"x" * 1000) == b"x" * 1000
        finally:
            for sock in held:
                sock.close()
        lines = [line for line in proxy.stderr().splitlines() if "refused at the cap of 3" in line]
        intervals = 1 + int((time.monotonic() - first) // REFUSAL_REPORT_S)
    assert 1 <= len(lines) <= intervals, proxy.stderr()
    assert lines[0].startswith("network-sim proxy: 1 connection(s) refused"), proxy.stderr()


def _echo_once_a_slot_is_free(addr: tuple[str, int], payload: bytes) -> bytes:
    """Echo ``payload``, trying again while the proxy refuses (it frees a slot once it sees the close)."""
    deadline = time.monotonic() + TIMEOUT
    while True:
        try:
            echoed = endpoint.echo(addr, payload, TIMEOUT)
        except OSError:  # refused while our bytes were in flight: a reset
            echoed = b""
        if echoed or time.monotonic() > deadline:
            return echoed
        time.sleep(0.05)


def test_hundred_concurrent_connections(server: Running) -> None:
    with _proxy(server, "--delay-ms", "10", "--rate-mbit", "200", "--jitter-ms", "2") as proxy:
        with ThreadPoolExecutor(100) as pool:
            payloads = [_payload(30_000 + 997 * i, seed=i) for i in range(100)]
            echoed = list(pool.map(lambda p: endpoint.echo(proxy.addr, p, TIMEOUT), payloads))
    assert sum(e == p for e, p in zip(echoed, payloads)) == 100


@pytest.mark.parametrize("delay_ms", [20.0, 120.0])
def test_one_way_delay_within_tolerance(server: Running, delay_ms: float) -> None:
    """Never early; and late by the delay asked for, over what the same probes take through a proxy with no
    delay in the same run (the proxy's own forwarding). Each side's fastest probe is compared: the forwarding of
    the others grows and varies with the load on the machine, the fastest's hardly."""
    with _proxy(server) as proxy:
        baseline = endpoint.probes(proxy.addr, 60, 0.01, TIMEOUT)
    with _proxy(server, "--delay-ms", f"{delay_ms:g}") as proxy:
        probes = endpoint.probes(proxy.addr, 60, 0.01, TIMEOUT)
    for direction in ("up_s", "down_s"):
        values = [getattr(p, direction) * 1e3 for p in probes]
        forwarding = min(getattr(p, direction) * 1e3 for p in baseline)
        added = min(values) - forwarding
        assert added == pytest.approx(delay_ms, abs=2.0 + 0.03 * delay_ms), (direction, forwarding)
        assert min(values) >= delay_ms - 0.05  # never early


def test_a_late_first_read_does_not_make_the_link_look_faster() -> None:
    """A receiver scheduled 80 ms late reads 1 KB, then the link's backlog at once, then 1 MB every 100 ms (10
    MB/s): the goodput window opens once a tenth of the bytes is in, so the backlog is not counted as fast."""
    ms = 1_000_000
    arrivals = [(1_000, 0), (800_000, 1 * ms)] + [(800_000 + k * 1_000_000, (1 + 100 * k) * ms) for k in range(1, 10)]
    start_bytes, start = endpoint.window_start(arrivals)
    assert (start_bytes, start) == (1_800_000, 101 * ms)
    transfer = endpoint.Transfer(arrivals[-1][0], True, start / 1e9, arrivals[-1][1] / 1e9, start_bytes)
    assert transfer.goodput_mbit == pytest.approx(80.0)  # 1 MB per 100 ms
    first_read = endpoint.Transfer(arrivals[-1][0], True, 0.0, arrivals[-1][1] / 1e9, 1_000)
    assert first_read.goodput_mbit > 1.05 * 80.0  # the backlog counted from the first read: the bias removed
    assert endpoint.window_start([]) == (0, 0)


#: Goodput may exceed the link's rate by this factor at most: the link model's own error, whatever the load.
RATE_CEILING = 1.07
#: Goodput may fall this far under the rate. A proxy, endpoint or client starved of CPU delivers late but never early:
#: beside two busy loops a 1 s transfer at 40 Mbit/s can measure 31 Mbit/s. The floor still catches a rate applied
#: twice or in the wrong unit; `network-sim selftest` holds goodput to ±5 % on a quiet machine.
RATE_FLOOR = 0.6


def assert_rate(goodput_mbit: float, rate_mbit: float) -> None:
    assert RATE_FLOOR * rate_mbit <= goodput_mbit <= RATE_CEILING * rate_mbit, (goodput_mbit, rate_mbit)


@pytest.mark.parametrize("rate_mbit", [4.0, 40.0])
def test_goodput_within_tolerance(server: Running, rate_mbit: float, tmp_path: Path) -> None:
    """Both directions carry the rate. A proxy stalled by a starved machine writes what fell due meanwhile at once,
    which a window opening after the stall measures as faster than the link: such a run, which the proxy's own
    lateness report calls unreliable, is measured again (three runs at most); the last run is judged."""
    from network_sim.chunklog import read_lateness

    nbytes = int(rate_mbit * 1e6 / 8 * 1.0)  # 1 s of link time
    for attempt in range(3):
        lateness = tmp_path / f"lateness_{attempt}.json"
        with _proxy(server, "--rate-mbit", f"{rate_mbit:g}", "--delay-ms", "5", "--lateness", str(lateness)) as proxy:
            down = endpoint.download(proxy.addr, nbytes, 1, TIMEOUT)
            up = endpoint.upload(proxy.addr, nbytes, 2, TIMEOUT)
        fast = max(down.goodput_mbit, up.goodput_mbit) > RATE_CEILING * rate_mbit
        if not (fast and not read_lateness(lateness)["reliable"]):
            break
    for result in (down, up):
        assert result.intact
        assert_rate(result.goodput_mbit, rate_mbit)


def test_connections_share_the_rate(server: Running) -> None:
    """The rate belongs to the link: two concurrent downloads together get it, not twice it."""
    nbytes = 750_000
    with _proxy(server, "--rate-mbit", "8") as proxy:
        with ThreadPoolExecutor(2) as pool:
            pair = list(pool.map(lambda seed: endpoint.download(proxy.addr, nbytes, seed, TIMEOUT), (1, 2)))
    assert all(t.intact for t in pair)
    assert_rate(endpoint.link_goodput_mbit(pair), 8.0)


def test_the_link_goodput_of_downloads_served_one_after_the_other_is_the_rate() -> None:
    """A shared FIFO serves two 1.25 MB downloads in turn at 10 Mbit/s (a 16 kB read every 12.8 ms, the second
    from 1 s on): merged, their reads measure the rate; each download's own window, spanned from the earliest
    start, leaves the second one's first tenth out of the bytes but not out of the time."""
    step_ns, size, reads = 12_800_000, 16_000, 78

    def download(first_ns: int) -> endpoint.Transfer:
        arrivals = [(size * (i + 1), first_ns + i * step_ns) for i in range(reads)]
        start_bytes, start = endpoint.window_start(arrivals)
        return endpoint.Transfer(size * reads, True, start / 1e9, arrivals[-1][1] / 1e9, start_bytes, tuple(arrivals))

    pair = [download(0), download(reads * step_ns)]
    assert endpoint.link_goodput_mbit(pair) == pytest.approx(10.0)
    span = max(t.last_s for t in pair) - min(t.start_s for t in pair)
    assert sum(t.nbytes - t.start_bytes for t in pair) * 8 / span / 1e6 < 0.96 * 10.0  # the bias it removes
    with pytest.raises(ValueError, match="arrivals"):
        endpoint.link_goodput_mbit([endpoint.Transfer(1, True, 0.0, 1.0, 0)])


def _read_log(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("dist", ["normal", "pareto"])
def test_jitter_never_reorders(server: Running, tmp_path: Path, dist: str) -> None:
    """Numbered messages sent every ~0.5 ms through 30 ms of jitter come back in order, and the log's
    releases per connection never go backwards."""
    log = tmp_path / "chunks.csv"
    count = 1500
    with _proxy(server, "--delay-ms", "40", "--jitter-ms", "30", "--jitter-dist", dist, "--log", str(log)) as proxy:
        with endpoint.connect(proxy.addr, b"E", TIMEOUT) as sock:

            def send() -> None:
                for i in range(count):
                    sock.sendall(struct.pack("!I", i))
                    time.sleep(0.0005)
                sock.shutdown(socket.SHUT_WR)

            sender = threading.Thread(target=send, daemon=True)
            sender.start()
            received = bytearray()
            while data := sock.recv(65536):
                received += data
            sender.join(TIMEOUT)
    assert list(struct.unpack(f"!{count}I", bytes(received))) == list(range(count))
    rows = _read_log(log)
    for direction in ("up", "down"):
        releases = [
            float(r["release_s"]) for r in sorted(rows, key=lambda r: int(r["seq"])) if r["direction"] == direction
        ]
        assert len(releases) > 50 and all(a <= b for a, b in zip(releases, releases[1:]))
    # The jitter reached the process: without it every chunk is released at its ready time plus the same 40 ms
    # (a spread of rounding only, 1e-15 of the delay); with it, the delays vary and none is negative. How wide the
    # spread is depends on how the messages were cut into chunks, so it is the link model's test
    # (tests/network_sim/test_link.py) that holds its size; here it only has to be far from none.
    held = [float(r["release_s"]) - float(r["ready_s"]) for r in rows if r["direction"] == "up"]
    assert min(held) >= 0 and statistics.pstdev(held) > 0.01 * statistics.fmean(held)


def test_full_queue_is_backpressure_not_loss(server: Running, tmp_path: Path) -> None:
    """A 20 kB queue at 8 Mbit/s under a 1.5 MB upload: every byte arrives, and the proxy reads the
    sender only when the queue has room (each chunk is read after the previous one was admitted)."""
    log = tmp_path / "chunks.csv"
    with _proxy(server, "--rate-mbit", "8", "--queue-bytes", "20000", "--log", str(log)) as proxy:
        result = endpoint.upload(proxy.addr, 1_500_000, 5, TIMEOUT)
    assert result.intact and result.nbytes == 1_500_000
    up = sorted((r for r in _read_log(log) if r["direction"] == "up"), key=lambda r: int(r["seq"]))
    waited = [float(r["admitted_s"]) - float(r["arrival_s"]) for r in up]
    assert max(waited) > 0.001  # the queue was full
    assert all(float(b["arrival_s"]) >= float(a["admitted_s"]) - 1e-6 for a, b in zip(up, up[1:]))
    for r in up:  # at each admission the bytes not yet serialized fit in the queue
        t = float(r["admitted_s"])
        queued = sum(
            min(int(o["bytes"]), max(0.0, float(o["finish_s"]) - t) * 1e6) for o in up if int(o["seq"]) <= int(r["seq"])
        )
        assert queued <= 20_000 + 1e-6


@pytest.mark.parametrize("flags", [("--rate-mbit", "0"), ("--loss", "1")])
def test_dead_link_ends_in_client_timeouts_while_the_proxy_stays_responsive(
    server: Running, flags: tuple[str, str]
) -> None:
    with _proxy(server, *flags, "--queue-bytes", "100000") as proxy:
        stuck = []
        for _ in range(3):
            sock = endpoint.connect(proxy.addr, b"E", TIMEOUT)  # accepted while the others are stuck
            sock.sendall(b"hello")
            sock.settimeout(0.5)  # nothing ever comes back: waiting longer only makes the test slower
            with pytest.raises(TimeoutError):
                sock.recv(10)
            stuck.append(sock)
        for sock in stuck:
            sock.close()
        assert proxy.stop(timeout=TIMEOUT) == 0  # it exits by itself, not killed, whatever is stuck in the link


def test_sigterm_closes_connections_cleanly(server: Running) -> None:
    proxy = _proxy(server, "--delay-ms", "5")
    with proxy:
        socks = [endpoint.connect(proxy.addr, b"E", TIMEOUT) for _ in range(3)]
        for sock in socks:
            sock.sendall(b"ping")
            assert endpoint.recv_exactly(sock, 4) == b"ping"
        proxy.proc.send_signal(signal.SIGTERM)
        assert proxy.proc.wait(TIMEOUT) == 0
        for sock in socks:
            assert sock.recv(10) == b""  # FIN, not a reset
            sock.close()
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(proxy.addr, timeout=2.0)


def test_sigint_also_stops_the_proxy(server: Running) -> None:
    with _proxy(server) as proxy:
        os.kill(proxy.proc.pid, signal.SIGINT)
        assert proxy.proc.wait(TIMEOUT) == 0


def test_model_replays_the_logged_release_times(server: Running, tmp_path: Path) -> None:
    """Feed a fresh model the logged arrivals in the proxy's order: it reproduces every admission,
    serialization, loss and release time exactly; and the proxy never wrote a chunk early. How late it wrote them
    depends on the machine's load: each run reports that itself (``--lateness``, tests/network_sim/test_lateness.py)."""
    flags = dict(
        delay_ms=10.0, jitter_ms=4.0, jitter_dist="pareto", rate_mbit=30.0, queue_bytes=60_000, loss=0.02, seed=11
    )
    log = tmp_path / "chunks.csv"
    args = [
        "--delay-ms",
        "10",
        "--jitter-ms",
        "4",
        "--jitter-dist",
        "pareto",
        "--rate-mbit",
        "30",
        "--queue-bytes",
        "60000",
        "--loss",
        "0.02",
        "--seed",
        "11",
        "--log",
        str(log),
    ]
    with _proxy(server, *args) as proxy:
        jobs = [
            lambda: endpoint.download(proxy.addr, 600_000, 1, TIMEOUT),
            lambda: endpoint.upload(proxy.addr, 400_000, 2, TIMEOUT),
            lambda: endpoint.probes(proxy.addr, 100, 0.005, TIMEOUT),
            lambda: endpoint.echo(proxy.addr, _payload(200_000, 3), TIMEOUT),
        ]
        with ThreadPoolExecutor(4) as pool:
            outcomes = [f.result() for f in [pool.submit(job) for job in jobs]]
    assert outcomes[0].intact and outcomes[1].intact
    rows = sorted(_read_log(log), key=lambda r: int(r["seq"]))
    assert len(rows) > 100 and len({r["conn"] for r in rows}) == 4
    link = Link(link_config(**flags))  # type: ignore[arg-type]
    for r in rows:
        chunk = link.stream(int(r["conn"]), r["direction"]).send(int(r["bytes"]), float(r["arrival_s"]))
        assert (chunk.seq, repr(chunk.admitted), repr(chunk.finish), repr(chunk.ready), repr(chunk.release)) == (
            int(r["seq"]),
            r["admitted_s"],
            r["finish_s"],
            r["ready_s"],
            r["release_s"],
        )
    lateness = [float(r["sent_s"]) - float(r["release_s"]) for r in rows]
    assert min(lateness) >= -1e-6
    assert any(float(r["lost"]) > 0 for r in rows)  # the replay covered losses too


def test_unreachable_upstream_after_start_closes_only_that_client() -> None:
    """The upstream goes away while the proxy runs: a client is closed, and the proxy keeps serving."""
    with network_sim("server") as doomed:
        host, port = doomed.addr
        with network_sim("proxy", "--upstream", f"{host}:{port}") as proxy:
            doomed.stop()
            for _ in range(2):
                with endpoint.connect(proxy.addr, b"E", TIMEOUT) as sock:
                    try:
                        assert sock.recv(10) == b""  # closed (a reset when our byte was still unread)
                    except ConnectionResetError:
                        pass
            assert proxy.proc.poll() is None
            assert proxy.stderr().count("unreachable") == 2


def test_a_verdict_computed_with_numpy_counts_as_missed() -> None:
    import numpy as np

    from network_sim.selftest_checks import Check

    verdict = np.float64(2.0) <= 1.0  # a numpy bool, which `is False` does not match
    assert Check("added RTT", "lan", "added_rtt", "p99", "ms", 2.0, 1.0, "<= 1 ms", verdict).ok is False


@pytest.mark.slow
def test_selftest_writes_tidy_results_and_counts_missed_targets(tmp_path: Path) -> None:
    """A miniature self-test (seconds, not minutes): every check lands in the CSV with its configured
    value and target verdict, provenance and plot are written, and the return value counts the misses."""
    from gicore.results import read_rows
    from network_sim.selftest import BENCH, run_selftest
    from network_sim.selftest_checks import SelftestConfig

    tiny = SelftestConfig(
        probe_s=0.3,
        delays_ms=(5.0,),
        jitters=((20.0, 2.0, "normal"),),
        jitter_s=0.6,
        rates_mbit=(20.0,),
        bulk_bytes=200_000,
        bulk_s=0.3,
        bulk_max_s=1.0,
        loss_probes=20,
        trace_s=1.0,
        pings=100,
        overhead_bytes=8 << 20,
    )
    missed = run_selftest(tiny, tmp_path, seed=1)
    rows = read_rows(tmp_path / f"{BENCH}.csv")
    verdicts = [r for r in rows if r["stat"] == "target_met"]
    assert {r["metric"] for r in verdicts} >= {
        "added_rtt",
        "bulk_throughput",
        "one_way_delay",
        "jitter_std",
        "goodput",
        "loss_share",
        "loss_delay",
        "trace_goodput",
        "intact_transfers",
        "goodput_sum",
    }
    assert missed == sum(r["value"] == 0.0 for r in verdicts)
    intact = next(r for r in rows if r["metric"] == "intact_transfers" and r["stat"] == "value")
    assert (
        intact["value"]
        == next(r for r in rows if r["metric"] == "intact_transfers" and r["stat"] == "configured")["value"]
        >= 6
    )
    assert (tmp_path / f"{BENCH}.provenance.json").is_file() and (tmp_path / f"{BENCH}.png").stat().st_size > 10_000
