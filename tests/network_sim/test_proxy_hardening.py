"""The proxy against a hostile or careless user: idle and trickling sockets give their slots back, trace files are
read bounded and as text, a FIFO or device given as a file, an unwritable log and absurd flag values are one error
line, floods leave it serving."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import struct
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from gicore.error_policy import UserError
from network_sim import endpoint
from network_sim.cli import link_config
from network_sim.link import UP
from network_sim.process import Running, network_sim, proxy
from network_sim.proxy import MAX_HELD_BYTES, Proxy
from network_sim.trace import MAX_BYTES, MAX_LINES, Trace
from tests.helpers.cli import assert_user_error, check_user_error, run_main

TIMEOUT = 60.0


@pytest.fixture(scope="module")
def upstream() -> Iterator[tuple[str, int]]:
    """The endpoint server's address."""
    with network_sim("server") as running:
        yield running.addr


def echoes(addr: tuple[str, int], payload: bytes = b"ping") -> bool:
    """Whether a fresh connection through the proxy echoes ``payload`` (False: it was closed, i.e. refused)."""
    with endpoint.connect(addr, b"E", TIMEOUT) as sock:
        try:
            sock.sendall(payload)
            return endpoint.recv_exactly(sock, len(payload)) == payload
        except ConnectionError:  # closed before the echo: refused at the cap
            return False


def wait_closed(sock: socket.socket) -> None:
    """Wait until the peer closes ``sock`` (EOF or a reset); a socket left open fails on the timeout."""
    sock.settimeout(TIMEOUT)
    try:
        while sock.recv(4096):
            pass
    except ConnectionResetError:
        pass


def test_idle_sockets_give_their_slots_back(upstream: tuple[str, int]) -> None:
    """Sockets held open without a byte, both legs open or the upstream gone, fill the cap only until the
    idle timeout: then both legs are closed and new clients get through."""
    with proxy(upstream, "--max-connections", "4", "--idle-timeout-s", "1") as p:
        both_open = [endpoint.connect(p.addr, b"E", TIMEOUT) for _ in range(2)]
        upstream_gone = [endpoint.connect(p.addr, b"G", TIMEOUT) for _ in range(2)]
        for sock in upstream_gone:  # the source sends nothing and closes: the client keeps its socket
            sock.sendall(endpoint.SOURCE_REQUEST.pack(0, 0))
            assert sock.recv(10) == b""
        for sock in both_open:
            sock.sendall(b"x")
            assert endpoint.recv_exactly(sock, 1) == b"x"
        assert not echoes(p.addr), "a fifth connection got through a cap of 4"
        for sock in both_open:
            wait_closed(sock)
        deadline = time.monotonic() + TIMEOUT
        while not echoes(p.addr):  # the half-closed ones go at the same check, or the next
            assert time.monotonic() < deadline, "the idle connections kept their slots"
            time.sleep(0.2)
        assert all(echoes(p.addr) for _ in range(3))
        for sock in both_open + upstream_gone:
            sock.close()


def test_a_cap_beyond_the_file_descriptor_limit_is_lowered_and_said(upstream: tuple[str, int]) -> None:
    """200 descriptors less the proxy's 64 hold 68 connections of two sockets each: the cap is lowered to that, in
    one stderr line (the proxy lowered it without a word), and the 69th connection is refused."""
    limit = ["prlimit", "--nofile=200:200"]
    with proxy(upstream, "--max-connections", "1024", prefix=limit) as p:
        said = [line for line in p.stderr().splitlines() if "lowered" in line]
        assert said == [
            "network-sim proxy: --max-connections lowered to 68 to fit the file-descriptor limit 200 (raise it with "
            "ulimit -n)"
        ], p.stderr()
        held = [endpoint.connect(p.addr, b"E", TIMEOUT) for _ in range(68)]
        for sock in held:
            sock.sendall(b"x")
            assert endpoint.recv_exactly(sock, 1) == b"x"
        assert not echoes(p.addr), "a 69th connection got through"
        for sock in held:
            sock.close()


def test_a_connection_that_moves_bytes_or_has_bytes_due_is_not_idle(upstream: tuple[str, int]) -> None:
    """Echoes of 100 bytes every 50 ms for 2.5 idle timeouts (16 kB per timeout counted, 4 x 100 bytes per echo:
    well over the default --idle-min-bytes even if a busy machine runs a tenth of them), and a round trip whose
    delay is 3 idle timeouts long, both come through whole."""
    with proxy(upstream, "--idle-timeout-s", "2") as p:
        with endpoint.connect(p.addr, b"E", TIMEOUT) as sock:
            end = time.monotonic() + 5.0
            while time.monotonic() < end:
                sock.sendall(b"k" * 100)
                assert endpoint.recv_exactly(sock, 100) == b"k" * 100
                time.sleep(0.05)
    with proxy(upstream, "--idle-timeout-s", "0.5", "--delay-ms", "1500") as p:
        assert echoes(p.addr, struct.pack("!Q", 7))


def trickle(sock: socket.socket, stop: threading.Event, gap_s: float) -> None:
    """Echo one byte every ``gap_s`` on ``sock`` until ``stop`` or the proxy closes it."""
    try:
        while not stop.wait(gap_s):
            sock.sendall(b"t")
            if sock.recv(1) != b"t":
                return
    except OSError:  # closed by the proxy: what the test waits for
        return


def test_trickling_clients_do_not_keep_their_slots(upstream: tuple[str, int]) -> None:
    """Two clients echo a byte every 0.1 s (40 bytes a second counted) at a cap of 2 with a 1 s idle timeout and
    --idle-min-bytes 400: the slots are theirs at first, but they move fewer bytes per timeout than the minimum, so
    both are closed and a new client gets through; a third that moves 100 bytes every 20 ms is kept meanwhile."""
    args = ("--max-connections", "3", "--idle-timeout-s", "1", "--idle-min-bytes", "400")
    with proxy(upstream, *args) as p:
        stop = threading.Event()
        tricklers = [endpoint.connect(p.addr, b"E", TIMEOUT) for _ in range(2)]
        threads = [threading.Thread(target=trickle, args=(s, stop, 0.1), daemon=True) for s in tricklers]
        with endpoint.connect(p.addr, b"E", TIMEOUT) as busy:
            try:
                for t in threads:
                    t.start()
                assert not echoes(p.addr), "a fourth connection got through a cap of 3"
                deadline = time.monotonic() + TIMEOUT
                while any(t.is_alive() for t in threads):  # each ends once the proxy closed its socket
                    assert time.monotonic() < deadline, "trickling connections kept their slots"
                    busy.sendall(b"b" * 100)
                    assert endpoint.recv_exactly(busy, 100) == b"b" * 100  # raises if the proxy closed it
                    time.sleep(0.02)
                assert echoes(p.addr)
            finally:
                stop.set()
                for s in tricklers:
                    s.close()


# -- trace files: bounded, ASCII text, errors naming file and line ----------------------------------------------
@pytest.mark.parametrize(
    ("content", "line", "what"),
    [
        pytest.param(b"10\n20\n\x92\x00\xff\n", 3, "byte 0x92 is not ASCII text", id="binary"),
        pytest.param("10\n20\n3é\n".encode(), 3, "byte 0xc3 is not ASCII text", id="utf8"),
        pytest.param(b"10\n" + b"9" * 5000 + b"\n", 2, "is above 1000000000 ms", id="huge-timestamp"),
        pytest.param(b"10\n1_000\n", 2, "is not a whole number", id="underscore"),
        pytest.param(b"10\n+20\n", 2, "is not a whole number", id="plus-sign"),
    ],
)
def test_a_bad_trace_file_is_one_error_naming_file_and_line(
    tmp_path: Path, content: bytes, line: int, what: str
) -> None:
    path = tmp_path / "bad.trace"
    path.write_bytes(content)
    with pytest.raises(UserError) as err:
        Trace.load(path)
    assert f"trace {path} line {line}" in str(err.value) and what in str(err.value)


def test_a_trace_is_read_bounded(tmp_path: Path) -> None:
    huge = tmp_path / "huge.trace"
    with huge.open("wb") as fh:
        fh.truncate(4 * MAX_BYTES)  # sparse: read no further than the bound
    with pytest.raises(UserError, match=f"trace {huge} is larger than {MAX_BYTES // 2**20} MiB"):
        Trace.load(huge)
    with pytest.raises(UserError, match="trace /dev/zero is a character device, not a regular file"):
        Trace.load("/dev/zero")  # endless: not read at all
    many = tmp_path / "many.trace"
    many.write_bytes(b"1\n" * (MAX_LINES + 1))
    with pytest.raises(UserError, match=f"has more than {MAX_LINES} lines"):
        Trace.load(many)


@pytest.mark.parametrize("flag", ["--trace-up", "--trace-down"])
def test_the_proxy_refuses_an_endless_or_binary_trace_with_one_line(
    tmp_path: Path, flag: str, monkeypatch: pytest.MonkeyPatch, capfd
) -> None:
    (tmp_path / "bin.trace").write_bytes(bytes(range(256)))
    os.mkfifo(tmp_path / "fifo.trace")  # read, it would block until a writer opened it: forever
    for trace in ("/dev/zero", "bin.trace", "fifo.trace"):
        argv = ["network-sim", "proxy", "--upstream", "127.0.0.1:9", flag, trace]
        line = check_user_error(run_main(argv, tmp_path, monkeypatch, capfd), trace)
        assert trace == "bin.trace" or f"{flag} {trace} is a " in line


# -- the per-chunk log -------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("log", "why"),
    [
        ("/dev/full", "is a character device, not a regular file"),
        (".", "is a directory, not a regular file"),
        ("fifo", "is a FIFO, not a regular file"),  # opened to write, it would block until a reader came
        ("/proc/version", "cannot be written ("),  # regular, but the kernel takes no write
    ],
)
def test_a_log_that_cannot_be_written_is_one_error_line(
    upstream: tuple[str, int], tmp_path: Path, log: str, why: str
) -> None:
    host, port = upstream
    os.mkfifo(tmp_path / "fifo")
    line = assert_user_error(["network-sim", "proxy", "--upstream", f"{host}:{port}", "--log", log], log, tmp_path)
    assert f"--log {log} {why}" in line


def test_a_log_that_fails_mid_run_stops_the_proxy_with_one_error_line(
    upstream: tuple[str, int], tmp_path: Path
) -> None:
    """A file-size limit (as a full disk) hit after the start: the proxy shuts down and says why, exit 2."""
    host, port = upstream
    log = tmp_path / "chunks.csv"
    command = f"ulimit -f 16 && exec {sys.executable} -m network_sim proxy --upstream {host}:{port} --log {log}"
    with Running(["bash", "-c", command], TIMEOUT) as p:
        p.readline(TIMEOUT)
        with pytest.raises(ConnectionError):
            for _ in range(100):  # each echo logs ~30 rows of ~130 bytes: the 16 KiB limit comes within 5
                endpoint.echo(p.addr, bytes(3_000_000), TIMEOUT)
        status = p.proc.wait(TIMEOUT)
        err = p.stderr()
    assert status == 2, err
    assert err.splitlines() == [f"error: --log {log} cannot be written (File too large): give a writable file path"]


# -- memory: what a flood can make the proxy hold ---------------------------------------------------------------
#: Bytes one read of a socket may bring (asyncio's read size); a sender is held after the read that passes the bound.
READ_BYTES = 2**18


def held_peak(upstream: tuple[str, int], senders: int, max_held_bytes: int) -> tuple[int, list[endpoint.Transfer]]:
    """The most stream bytes an in-process proxy with a 1 s delay held while ``senders`` clients each uploaded
    2 MiB through it at once (a connection's window takes 3 MiB), and the sink's reports."""

    async def run() -> tuple[int, list[endpoint.Transfer]]:
        loop = asyncio.get_running_loop()
        link = link_config(delay_ms=1000.0)
        p = Proxy(link, upstream, max_connections=senders, max_held_bytes=max_held_bytes)
        server = await loop.create_server(p.accept, "127.0.0.1", 0)
        addr = server.sockets[0].getsockname()[:2]
        with ThreadPoolExecutor(senders) as pool:
            jobs = [
                loop.run_in_executor(pool, endpoint.upload, addr, 2 * 2**20, seed, TIMEOUT) for seed in range(senders)
            ]
            peak = 0
            while not all(job.done() for job in jobs):
                peak = max(peak, p.held_bytes)
                await asyncio.sleep(0.005)
            transfers = [job.result() for job in jobs]
        server.close()
        p.close_all()
        return peak, transfers

    return asyncio.run(run())


@pytest.mark.slow
def test_a_flood_holds_bounded_memory_and_still_delivers_every_byte(upstream: tuple[str, int]) -> None:
    senders, bound = 8, 2**20
    peak, transfers = held_peak(upstream, senders, bound)
    assert peak <= bound + senders * READ_BYTES, peak
    assert all(t.intact for t in transfers)
    unbounded, _ = held_peak(upstream, senders, MAX_HELD_BYTES)  # what the same flood holds below the default bound
    assert unbounded > 2 * (bound + senders * READ_BYTES), unbounded


def test_an_upstream_that_connects_after_its_client_left_is_closed() -> None:
    """A client that resets while the proxy still connects upstream: the late upstream leg is closed, not kept."""

    class Leg(asyncio.Transport):
        closed = False

        def close(self) -> None:
            self.closed = True

    async def run() -> Leg:
        p = Proxy(link_config(), ("127.0.0.1", 9))
        p.accept()  # a client connects
        (conn,) = p.connections.values()
        conn.close()  # what the client's reset leads to
        late = Leg()
        conn.upstream.connection_made(late)
        p.close_all()
        return late

    assert asyncio.run(run()).closed


def test_clients_that_leave_before_their_answer_cost_no_traceback(upstream: tuple[str, int]) -> None:
    """Clients that send, half-close and leave at once: the answer and the EOF the proxy then forwards meet a reset
    socket, which ends that connection quietly, and the proxy serves on."""
    with proxy(upstream, "--delay-ms", "5") as running:
        for _ in range(20):
            with socket.create_connection(running.addr, timeout=TIMEOUT) as sock:
                sock.sendall(b"E" + b"x" * 1000)
                sock.shutdown(socket.SHUT_WR)
        assert echoes(running.addr)  # released after theirs on the shared link: they have been written by then
        running.proc.send_signal(signal.SIGTERM)
        assert running.proc.wait(TIMEOUT) == 0
        assert "Traceback" not in running.stderr(), running.stderr()


def test_nothing_is_written_to_a_leg_already_closing() -> None:
    """A leg whose send failed (or that the proxy closed) is closing until its connection_lost comes: chunks
    released meanwhile are dropped, not written (asyncio logs a warning for each write past the fifth, one per
    chunk: a client streaming to a server that closed on it filled the proxy's stderr)."""

    class Closing(asyncio.Transport):
        writes = 0

        def is_closing(self) -> bool:
            return True

        def write(self, data: bytes | bytearray | memoryview) -> None:
            self.writes += 1

        def close(self) -> None:
            pass

    async def run() -> Closing:
        p = Proxy(link_config(), ("127.0.0.1", 9))
        p.accept()  # a client connects
        (conn,) = p.connections.values()
        leg = Closing()
        conn.upstream.connection_made(leg)
        for _ in range(10):
            conn.pipes[UP].feed(b"x" * 1000)  # unshaped: released and flushed at once
        await asyncio.sleep(0)
        p.close_all()
        return leg

    assert asyncio.run(run()).writes == 0


# -- rates: 0 is a dead link; a positive rate too small to ever finish a chunk is refused ------------------------
def test_a_vanishing_rate_is_refused_in_one_line_and_zero_stays_a_dead_link(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd
) -> None:
    for flag in ("--rate-mbit", "--rate-up-mbit"):
        argv = ["network-sim", "proxy", "--upstream", "127.0.0.1:9", flag, "1e-300"]
        line = check_user_error(run_main(argv, tmp_path, monkeypatch, capfd), "rate_mbit = 1e-300")
        assert "must be 0 (a dead link) or >= 0.001" in line
    assert link_config(rate_mbit=0.0).up.rate_mbit == 0.0 and link_config(rate_mbit=1e-3).down.rate_mbit == 1e-3


def test_a_process_that_does_not_start_in_time_is_not_left_running() -> None:
    """Running waits for 'listening on'; a timeout (as a Ctrl-C) while it waits stops the child."""
    started: list[Running] = []
    original = Running.readline

    def remember(self: Running, timeout: float) -> str:
        started.append(self)
        return original(self, timeout)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Running, "readline", remember)
        with pytest.raises(TimeoutError):
            Running([sys.executable, "-c", "import time; time.sleep(600)"], timeout=0.5)
    assert started and started[0].proc.poll() is not None  # ended, not orphaned
