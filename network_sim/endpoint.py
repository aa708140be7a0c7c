"""The two ends the proxy sits between in the self-test and the tests: a server and blocking clients.

The server's first byte on a connection picks its mode:

- ``E`` echo: writes back every byte it reads, until EOF.
- ``S`` sink: reads until EOF, then answers one JSON line: bytes, SHA-256, and the CLOCK_MONOTONIC times
  of the goodput window's start (:func:`window_start`) and the last byte (goodput is measured where the bytes
  arrive).
- ``G`` source: reads ``!QQ`` (byte count, seed) and sends that many bytes of :func:`blocks`, then EOF.
- ``P`` probe: for every ``!QQ`` (sequence number, client send time in ns) it receives, answers
  ``!QQQQ`` (sequence, client send time, server receive time, server send time). Client and server run
  on one machine, so CLOCK_MONOTONIC is shared and one-way delays are measured directly.

The byte streams are seeded and unique block by block, so a SHA-256 comparison catches lost,
duplicated or reordered bytes.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import random
import signal
import socket
import struct
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import suppress
from dataclasses import dataclass, field

import numpy as np

PROBE = struct.Struct("!QQ")
PROBE_REPLY = struct.Struct("!QQQQ")
SOURCE_REQUEST = struct.Struct("!QQ")
#: Size of one generated block (its 8-byte words are XORed with a per-block key, so blocks differ).
BLOCK_BYTES = 1 << 20
_READ_BYTES = 1 << 20


def blocks(nbytes: int, seed: int) -> Iterator[bytes]:
    """The seeded byte stream of ``nbytes`` bytes, in blocks of at most :data:`BLOCK_BYTES`."""
    base = np.frombuffer(random.Random(seed).randbytes(BLOCK_BYTES), dtype=np.uint64)
    index = 0
    while nbytes > 0:
        key = np.uint64((index + 1) * 0x9E3779B97F4A7C15 % 2**64)
        block = (base ^ key).tobytes()[: min(nbytes, BLOCK_BYTES)]
        nbytes -= len(block)
        index += 1
        yield block


def digest(nbytes: int, seed: int) -> str:
    """SHA-256 of the stream :func:`blocks` makes."""
    h = hashlib.sha256()
    for block in blocks(nbytes, seed):
        h.update(block)
    return h.hexdigest()


# --- server ---------------------------------------------------------------------------------------------


async def _handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    sock = writer.get_extra_info("socket")
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        mode = await reader.read(1)
        if mode == b"E":
            while data := await reader.read(_READ_BYTES):
                writer.write(data)
                await writer.drain()
        elif mode == b"S":
            h, total, arrivals = hashlib.sha256(), 0, []
            while data := await reader.read(_READ_BYTES):
                total += len(data)
                arrivals.append((total, time.monotonic_ns()))
                h.update(data)
            start_bytes, start = window_start(arrivals)
            last = arrivals[-1][1] if arrivals else 0
            report = {
                "bytes": total,
                "sha256": h.hexdigest(),
                "start_ns": start,
                "last_ns": last,
                "start_bytes": start_bytes,
            }
            writer.write(json.dumps(report).encode() + b"\n")
        elif mode == b"G":
            nbytes, seed = SOURCE_REQUEST.unpack(await reader.readexactly(SOURCE_REQUEST.size))
            for block in blocks(nbytes, seed):
                writer.write(block)
                await writer.drain()
        elif mode == b"P":
            while True:
                try:
                    message = await reader.readexactly(PROBE.size)
                except asyncio.IncompleteReadError:
                    break
                received = time.monotonic_ns()
                seq, sent = PROBE.unpack(message)
                writer.write(PROBE_REPLY.pack(seq, sent, received, time.monotonic_ns()))
        if writer.can_write_eof():
            writer.write_eof()
        await writer.drain()
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        writer.close()


async def serve(host: str, port: int) -> None:
    """Serve every mode until SIGTERM or SIGINT; prints ``listening on HOST:PORT`` first."""
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    server = await asyncio.start_server(_handle, host, port, limit=4 * _READ_BYTES)
    bound_host, bound_port = server.sockets[0].getsockname()[:2]
    print(f"listening on {bound_host}:{bound_port}", flush=True)
    await stop.wait()
    server.close()


# --- clients (blocking sockets; every call bounded by ``timeout``) ---------------------------------------


def connect(addr: tuple[str, int], mode: bytes, timeout: float) -> socket.socket:
    """A TCP_NODELAY connection that has announced ``mode``."""
    sock = socket.create_connection(addr, timeout=timeout)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.sendall(mode)
    return sock


def recv_exactly(sock: socket.socket, nbytes: int) -> bytes:
    parts, left = [], nbytes
    while left:
        data = sock.recv(left)
        if not data:
            raise ConnectionError(f"connection closed {left} bytes short of {nbytes}")
        parts.append(data)
        left -= len(data)
    return b"".join(parts)


@dataclass(frozen=True)
class Transfer:
    """A bulk transfer as its receiver saw it (times in CLOCK_MONOTONIC seconds)."""

    nbytes: int
    intact: bool  # the SHA-256 matched the sent stream
    start_s: float  # the goodput window's start (:func:`window_start`)
    last_s: float  # last byte arrived
    start_bytes: int  # bytes arrived by start_s (outside the window)
    #: Each read's running byte total and CLOCK_MONOTONIC ns where this end received them (downloads only).
    arrivals: tuple[tuple[int, int], ...] = field(default=(), repr=False)

    @property
    def goodput_mbit(self) -> float:
        """Receiver goodput over the window from ``start_s`` to the last byte, Mbit/s."""
        span = self.last_s - self.start_s
        return (self.nbytes - self.start_bytes) * 8 / span / 1e6 if span > 0 else float("nan")


#: The goodput window opens at the first read by which this share of the bytes has arrived. A receiver scheduled
#: late (a busy machine) reads the backlog of the link's first milliseconds at once; counted inside the window,
#: those bytes would make the link look faster than its rate.
WINDOW_START = 0.1


def window_start(arrivals: list[tuple[int, int]]) -> tuple[int, int]:
    """(bytes arrived, time) of the first read whose running total reaches :data:`WINDOW_START` of the whole;
    ``arrivals``: each read's running total and time; (0, 0) without any."""
    if not arrivals:
        return 0, 0
    return next(a for a in arrivals if a[0] >= WINDOW_START * arrivals[-1][0])


def link_goodput_mbit(downloads: Sequence[Transfer]) -> float:
    """Goodput of the link that carried ``downloads`` at once, Mbit/s: their reads merged in time order, over the
    window from the read by which :data:`WINDOW_START` of all their bytes had arrived to the last byte.

    Each download's own window would not do: a shared FIFO may serve them one after the other, and then the span
    from the earliest window's start holds the later download's first tenth, which its own window leaves out
    (two 1.25 MB downloads at 10 Mbit/s measure 9.47 Mbit/s so, on a link that was busy throughout)."""
    if not downloads or not all(t.arrivals for t in downloads):
        raise ValueError("link_goodput_mbit needs downloads that received bytes (their arrivals)")
    reads = sorted(
        (ns, total - before) for t in downloads for (before, _), (total, ns) in zip(((0, 0), *t.arrivals), t.arrivals)
    )
    merged, total = [], 0
    for ns, nbytes in reads:
        total += nbytes
        merged.append((total, ns))
    start_bytes, start = window_start(merged)
    span_s = (merged[-1][1] - start) / 1e9
    return (total - start_bytes) * 8 / span_s / 1e6 if span_s > 0 else float("nan")


def upload(addr: tuple[str, int], nbytes: int, seed: int, timeout: float) -> Transfer:
    """Send ``nbytes`` of the seeded stream to a sink and return what the sink measured."""
    with connect(addr, b"S", timeout) as sock:
        for block in blocks(nbytes, seed):
            sock.sendall(block)
        sock.shutdown(socket.SHUT_WR)
        line = b""
        while not line.endswith(b"\n"):
            data = sock.recv(4096)
            if not data:
                raise ConnectionError("sink closed without a report")
            line += data
    report = json.loads(line)
    return Transfer(
        report["bytes"],
        report["bytes"] == nbytes and report["sha256"] == digest(nbytes, seed),
        report["start_ns"] / 1e9,
        report["last_ns"] / 1e9,
        report["start_bytes"],
    )


def download(addr: tuple[str, int], nbytes: int, seed: int, timeout: float) -> Transfer:
    """Fetch ``nbytes`` of the seeded stream from a source, timing the arrivals here."""
    h, total, arrivals = hashlib.sha256(), 0, []
    with connect(addr, b"G", timeout) as sock:
        sock.sendall(SOURCE_REQUEST.pack(nbytes, seed))
        while data := sock.recv(_READ_BYTES):
            total += len(data)
            arrivals.append((total, time.monotonic_ns()))
            h.update(data)
    start_bytes, start = window_start(arrivals)
    last = arrivals[-1][1] if arrivals else 0
    intact = total == nbytes and h.hexdigest() == digest(nbytes, seed)
    return Transfer(total, intact, start / 1e9, last / 1e9, start_bytes, tuple(arrivals))


def echo(addr: tuple[str, int], payload: bytes, timeout: float) -> bytes:
    """Send ``payload`` to an echo server, half-close, and return everything echoed back."""
    received = bytearray()
    with connect(addr, b"E", timeout) as sock:

        def send() -> None:
            with suppress(OSError):  # reset or closed: what came back so far is the answer, short
                sock.sendall(payload)
                sock.shutdown(socket.SHUT_WR)

        sender = threading.Thread(target=send, daemon=True)
        sender.start()
        while data := sock.recv(_READ_BYTES):
            received += data
        sender.join(timeout)
    return bytes(received)


def round_trips(addr: tuple[str, int], count: int, timeout: float) -> list[float]:
    """``count`` back-to-back probe round trips on one connection, seconds each."""
    times = []
    with connect(addr, b"P", timeout) as sock:
        for seq in range(count):
            start = time.monotonic_ns()
            sock.sendall(PROBE.pack(seq, start))
            recv_exactly(sock, PROBE_REPLY.size)
            times.append((time.monotonic_ns() - start) / 1e9)
    return times


@dataclass(frozen=True)
class Probe:
    """One probe's one-way delays (seconds)."""

    sent_s: float
    up_s: float  # client -> server
    down_s: float  # server -> client


def probes(addr: tuple[str, int], count: int, interval_s: float, timeout: float, seed: int = 0) -> list[Probe]:
    """Send ``count`` probes on one connection, spaced by exponential gaps of mean ``interval_s`` (so they
    do not lock onto any period of the link), and time both directions of each."""
    rng = random.Random(seed)
    results: list[Probe] = []
    with connect(addr, b"P", timeout) as sock:

        def send_all() -> None:
            deadline = time.monotonic()
            for seq in range(count):
                deadline += rng.expovariate(1.0 / interval_s)
                time.sleep(max(0.0, deadline - time.monotonic()))
                sock.sendall(PROBE.pack(seq, time.monotonic_ns()))

        sender = threading.Thread(target=send_all, daemon=True)
        sender.start()
        for _ in range(count):
            seq, sent, received, replied = PROBE_REPLY.unpack(recv_exactly(sock, PROBE_REPLY.size))
            back = time.monotonic_ns()
            results.append(Probe(sent / 1e9, (received - sent) / 1e9, (back - replied) / 1e9))
        sender.join(timeout)
    return results
