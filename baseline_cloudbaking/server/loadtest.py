"""A load generator for ``cloudbaking-server`` on this machine (loopback addresses only).

One asyncio loop and a minimal HTTP/1.1 keep-alive client (no client library in the timed path, so the
latencies are the server's and the loopback's, not a client's): paced hit clients that time each
request, a burst of concurrent misses, and a flood of idle connections that send nothing. Beside it, a closed
loop (:func:`run_closed_loop`): client threads sending hit requests back to back through httpx, as the cloud
client does, for the throughput a server sustains (``bench service``).

    python -m baseline_cloudbaking.server.loadtest --url http://127.0.0.1:PORT --scene lung_plane \\
        --idle 20000 --misses 80 --hit-clients 32

prints one JSON object: hit latency percentiles, status counts of hits and misses, idle connections
opened and how many the server closed. ``bench load`` runs it against a server of its own and judges the
figures against their targets.

Instants (when a hit or miss was sent, the side load's window) are ``time.monotonic()``: on Linux one
system-wide clock, so the side process's instants compare with the hit clients'.
"""

from __future__ import annotations

import argparse
import asyncio
import ipaddress
import json
import multiprocessing
import signal
import socket
import struct
import threading
import time
from collections import Counter
from collections.abc import Coroutine
from concurrent.futures import ProcessPoolExecutor
from contextlib import suppress
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar
from urllib.parse import urlsplit

import numpy as np

from baseline_cloudbaking.protocol import unpack
from baseline_cloudbaking.server.limits import FD_RESERVE
from gicore.fd_budget import connection_budget

if TYPE_CHECKING:
    import httpx


def loopback(url: str) -> tuple[str, int]:
    """(host, port) of ``url``; ValueError unless the host is a loopback address (load stays on this machine)."""
    parts = urlsplit(url)
    host, port = parts.hostname or "", parts.port or 80
    if host != "localhost" and not ipaddress.ip_address(host).is_loopback:
        raise ValueError(f"{url}: load is sent to loopback addresses only (127.0.0.0/8, ::1, localhost)")
    return host, port


class Conn:
    """One keep-alive HTTP/1.1 connection."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.reader: asyncio.StreamReader | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def request(
        self, method: str, path: str, body: bytes = b"", headers: dict[str, str] | None = None
    ) -> tuple[int, dict[str, str], bytes]:
        if self.writer is None or self.writer.is_closing():
            self.reader, self.writer = await asyncio.open_connection(self.host, self.port)
        assert self.reader is not None
        lines = [f"{method} {path} HTTP/1.1", f"host: {self.host}:{self.port}", f"content-length: {len(body)}"]
        if body:
            lines.append("content-type: application/json")
        lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
        self.writer.write(("\r\n".join(lines) + "\r\n\r\n").encode() + body)
        head = await self.reader.readuntil(b"\r\n\r\n")
        status_line, *header_lines = head.decode("latin-1").split("\r\n")
        hdrs = {k.lower(): v.strip() for k, _, v in (h.partition(":") for h in header_lines if h)}
        content = await self.reader.readexactly(int(hdrs.get("content-length", "0")))
        if hdrs.get("connection", "").lower() == "close":
            self.close()
        return int(status_line.split()[1]), hdrs, content

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


#: Seconds without a single idle connection closed after which a server short of its expected closes is taken to
#: have stopped closing them (a CPU-starved one pauses for a second or two, not this long).
STALL_S = 30.0
#: Fields of :class:`LoadResult` that :meth:`LoadResult.summary` condenses instead of listing.
_PER_REQUEST = ("hit_ms", "hit_at", "misses", "side_window")


@dataclass
class LoadResult:
    hit_ms: list[float] = field(default_factory=list)
    hit_at: list[float] = field(default_factory=list)  # when each hit was sent (module docstring: instants)
    hit_status: Counter = field(default_factory=Counter)
    miss_status: Counter = field(default_factory=Counter)
    #: (status, sent, answered) of each answered miss.
    misses: list[tuple[int, float, float]] = field(default_factory=list)
    retry_after: Counter = field(default_factory=Counter)
    idle_opened: int = 0
    idle_closed_by_server: int = 0
    #: The side load's window: from sending the misses (and opening the flood) to releasing the flood.
    side_window: tuple[float, float] = (0.0, 0.0)
    errors: Counter = field(default_factory=Counter)

    def hits_sent_between(self, start: float, end: float) -> list[float]:
        """Latencies (ms) of the hits sent from ``start`` to ``end``."""
        return [ms for ms, at in zip(self.hit_ms, self.hit_at) if start <= at <= end]

    def failures(self) -> int:
        """Hits not answered 200, misses answered neither 200 nor 503 with Retry-After, failed connections."""
        bad_hits = sum(n for status, n in self.hit_status.items() if status != 200)
        bad_misses = sum(n for status, n in self.miss_status.items() if status not in (200, 503))
        no_retry = self.miss_status.get(503, 0) - sum(self.retry_after.values())
        return bad_hits + bad_misses + no_retry + sum(self.errors.values())

    def summary(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in _PER_REQUEST}
        out = {k: {str(c): n for c, n in v.items()} if isinstance(v, Counter) else v for k, v in out.items()}
        out["hits"] = len(self.hit_ms)
        out |= percentiles("hit", self.hit_ms)
        return out


def percentiles(name: str, ms: list[float]) -> dict[str, float]:
    """p50, p99 and max of ``ms`` as ``{name}_p50_ms`` ...; zeros when there are none."""
    values = np.asarray(ms) if ms else np.zeros(1)
    out = {f"{name}_{p}_ms": round(float(np.percentile(values, q)), 2) for p, q in (("p50", 50), ("p99", 99))}
    return out | {f"{name}_max_ms": round(float(values.max()), 2)}


def idle_room() -> int:
    """Idle connections this process can hold open: its file-descriptor limit, raised as the server raises its
    own, less the server's reserve for everything else."""
    return connection_budget(1 << 30, FD_RESERVE)[0]


async def _hit_client(
    host: str, port: int, body: bytes, stop: asyncio.Event, period_s: float, phase_s: float, res: LoadResult
) -> None:
    conn = Conn(host, port)
    loop = asyncio.get_running_loop()
    await asyncio.sleep(phase_s)
    next_t = loop.time()
    try:
        while not stop.is_set():
            sent, t0 = time.monotonic(), time.perf_counter()
            try:
                status, _, _ = await conn.request("POST", "/v1/gimap", body)
            except (OSError, asyncio.IncompleteReadError) as exc:
                res.errors[f"hit {type(exc).__name__}"] += 1
                conn.close()
                continue
            res.hit_ms.append((time.perf_counter() - t0) * 1e3)
            res.hit_at.append(sent)
            res.hit_status[status] += 1
            next_t += period_s
            await asyncio.sleep(max(0.0, next_t - loop.time()))
    finally:
        conn.close()


async def _miss(host: str, port: int, body: bytes, res: LoadResult) -> None:
    conn = Conn(host, port)
    sent = time.monotonic()
    try:
        status, headers, _ = await conn.request("POST", "/v1/gimap", body)
        res.misses.append((status, sent, time.monotonic()))
        res.miss_status[status] += 1
        if "retry-after" in headers:
            res.retry_after[headers["retry-after"]] += 1
    except (OSError, asyncio.IncompleteReadError) as exc:
        res.errors[f"miss {type(exc).__name__}"] += 1
    finally:
        conn.close()


#: SO_LINGER of a connection the flood abandons: closed with a reset, not a FIN.
_RESET_ON_CLOSE = struct.pack("ii", 1, 0)


async def _idle_flood(host: str, port: int, n: int, res: LoadResult, stop: asyncio.Event, rate: float) -> None:
    """Open ``n`` connections that send nothing, ``rate`` a second whether or not the earlier ones are through
    (independent clients: one whose handshake waits does not hold back the next), and hold each until the
    server closes it or ``stop`` is set; then reset it. A flood overflows a server's listen backlog: the kernel
    answers with SYN cookies and drops a completed handshake that finds the accept queue full, leaving a connection
    the server never saw. A FIN would carry the cookie again and have the server accept it only to see it close;
    a reset does not, so the server's count of accepted connections is of those that reached it while held."""
    held: set[asyncio.Task] = set()

    async def open_and_hold() -> None:
        try:
            reader, writer = await asyncio.open_connection(host, port)
        except OSError as exc:
            res.errors[f"idle {exc.strerror or type(exc).__name__}"] += 1
            return
        res.idle_opened += 1
        try:
            while not stop.is_set() and await reader.read(4096):
                pass  # a server's 503 refusal, then EOF
            res.idle_closed_by_server += not stop.is_set()
        except OSError:
            res.idle_closed_by_server += 1
        finally:
            if stop.is_set():
                with suppress(OSError):  # a connection the server reset has no socket left to set
                    writer.get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, _RESET_ON_CLOSE)
            writer.close()

    t0 = asyncio.get_running_loop().time()
    for i in range(n):
        if stop.is_set():
            break
        await asyncio.sleep(max(0.0, t0 + i / rate - asyncio.get_running_loop().time()))
        task = asyncio.ensure_future(open_and_hold())
        held.add(task)
        task.add_done_callback(held.discard)
    await stop.wait()
    for task in list(held):  # the connections the server left open are closed by this side
        task.cancel()
    await asyncio.gather(*held, return_exceptions=True)


async def _side_load(
    host: str, port: int, miss_bodies: list[bytes], idle: int, idle_rate: float, hold_s: float, keep: int | None
) -> LoadResult:
    """The misses (all at once) and the idle flood, then ``hold_s`` more with the flood held, and on while the
    server goes on closing idle connections (so that what it would close is not closed by this side first), and
    while it has closed fewer than all but ``keep`` of them (a starved server can close none for a second)."""
    res = LoadResult()
    stop = asyncio.Event()
    start = time.monotonic()
    if idle > idle_room():
        raise ValueError(f"{idle} idle connections do not fit this process's file-descriptor limit ({idle_room()})")
    flood = asyncio.ensure_future(_idle_flood(host, port, idle, res, stop, idle_rate))
    await asyncio.gather(*(_miss(host, port, body, res) for body in miss_bodies))
    while idle and res.idle_opened + sum(res.errors.values()) < idle and not flood.done():
        await asyncio.sleep(0.05)
    await asyncio.sleep(hold_s)
    closed, last_close = -1, time.monotonic()
    while idle:
        now = time.monotonic()
        if res.idle_closed_by_server != closed:  # a busy server is still working through the flood
            closed, last_close = res.idle_closed_by_server, now
        elif keep is None or closed >= res.idle_opened - keep or now - last_close > STALL_S:
            break
        await asyncio.sleep(hold_s)
    res.side_window = (start, time.monotonic())
    stop.set()
    await flood
    return res


def _ready() -> None:
    """Submitted first: the worker process imports this module before the measurement."""


def _side_process(
    host: str, port: int, miss_bodies: list[bytes], idle: int, idle_rate: float, hold_s: float, keep: int | None
) -> LoadResult:
    return asyncio.run(_side_load(host, port, miss_bodies, idle, idle_rate, hold_s, keep))


async def run_load(
    url: str,
    hit_body: dict[str, Any],
    miss_bodies: list[dict[str, Any]],
    *,
    hit_clients: int = 32,
    period_s: float = 0.02,
    idle: int = 0,
    idle_rate: float = 2000.0,
    settle_s: float = 3.0,
    hold_s: float | None = None,
    keep: int | None = None,
    max_s: float = 120.0,
) -> LoadResult:
    """Hit clients (each a request every ``period_s``, their phases spread evenly over the period, as
    independent clients are not in lockstep) running while another process sends ``miss_bodies`` at once
    and opens ``idle`` idle connections, ``idle_rate`` a second (in its own process, so that its work does
    not delay the hit clients' clocks), then holds them ``hold_s`` (default ``settle_s``), and with ``keep`` (the
    server's connection cap) until the server has closed all the others; the hit clients run ``settle_s`` before
    it (at most ``max_s`` in all)."""
    host, port = loopback(url)
    res = LoadResult()
    stop = asyncio.Event()
    hit = json.dumps(hit_body).encode()
    clients = [
        asyncio.ensure_future(_hit_client(host, port, hit, stop, period_s, i * period_s / hit_clients, res))
        for i in range(hit_clients)
    ]
    misses = [json.dumps(b).encode() for b in miss_bodies]
    try:
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            # started and this module imported before the clock matters
            await asyncio.get_running_loop().run_in_executor(pool, _ready)
            await asyncio.sleep(settle_s)
            side = asyncio.get_running_loop().run_in_executor(
                pool, _side_process, host, port, misses, idle, idle_rate, settle_s if hold_s is None else hold_s, keep
            )
            other = await asyncio.wait_for(side, max_s)
    finally:
        stop.set()
        await asyncio.gather(*clients, return_exceptions=True)
    res.miss_status, res.retry_after, res.errors = other.miss_status, other.retry_after, res.errors + other.errors
    res.misses, res.side_window = other.misses, other.side_window
    res.idle_opened, res.idle_closed_by_server = other.idle_opened, other.idle_closed_by_server
    return res


def http_client(url: str, read_timeout_s: float) -> httpx.Client:
    """A keep-alive httpx client of the server at ``url`` (``read_timeout_s`` bounds a miss's render)."""
    import httpx

    return httpx.Client(base_url=url, timeout=httpx.Timeout(read_timeout_s, connect=10.0))


def timed_post(client: httpx.Client, body: bytes) -> tuple[float, dict[str, Any]]:
    """Round trip of one GI-map request (seconds, request sent to last byte read) and the payload header;
    raises RuntimeError on a non-200 answer."""
    t0 = time.perf_counter()
    r = client.post("/v1/gimap", content=body, headers={"content-type": "application/json"})
    elapsed = time.perf_counter() - t0
    if r.status_code != 200:
        raise RuntimeError(f"POST /v1/gimap answered {r.status_code}: {r.text[:500]}")
    return elapsed, unpack(r.content)[0]


def run_closed_loop(
    url: str, bodies: list[bytes], clients: int, per_client: int, read_timeout_s: float
) -> tuple[list[float], int, float, list[str]]:
    """``clients`` threads, each sending ``per_client`` requests of stored views (``bodies`` in turn) back to
    back: latencies (s) of the hits, the error count (failed requests and answers that are no hit), the wall
    time (s) from the common start to the last answer, and the first errors."""
    loopback(url)
    start = threading.Barrier(clients + 1)
    latencies: list[list[float]] = [[] for _ in range(clients)]
    errors: list[list[str]] = [[] for _ in range(clients)]

    def worker(i: int) -> None:
        with http_client(url, read_timeout_s) as client:
            client.get("/health")  # open the keep-alive connection before the clock starts
            start.wait()
            for j in range(per_client):
                try:
                    seconds, header = timed_post(client, bodies[(i + j) % len(bodies)])
                except Exception as exc:  # noqa: BLE001 - any failure of a request is a counted error
                    errors[i].append(f"{type(exc).__name__}: {exc}"[:300])
                    continue
                if header.get("hit") is not True:
                    errors[i].append("not a hit")
                else:
                    latencies[i].append(seconds)

    threads = [threading.Thread(target=worker, args=(i,), daemon=True) for i in range(clients)]
    for t in threads:
        t.start()
    start.wait(timeout=60.0)
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    flat_errors = [e for errs in errors for e in errs]
    return [s for lat in latencies for s in lat], len(flat_errors), wall, flat_errors[:5]


T = TypeVar("T")


def run_interruptibly(coro: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(coro)`` with SIGTERM handled as asyncio handles Ctrl-C: ``coro`` is cancelled (its clean-up
    runs) and KeyboardInterrupt is raised here. A KeyboardInterrupt raised by a signal handler wherever the loop
    happens to be can instead leave the loop waiting for ever on a future nobody completes."""
    if threading.current_thread() is not threading.main_thread():
        return asyncio.run(coro)  # signals reach the main thread only

    async def cancelled_by_sigterm() -> T:
        task = asyncio.current_task()
        assert task is not None
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, task.cancel)
        return await coro

    previous = signal.getsignal(signal.SIGTERM)
    try:
        return asyncio.run(cancelled_by_sigterm())
    except asyncio.CancelledError:
        raise KeyboardInterrupt from None
    finally:
        signal.signal(signal.SIGTERM, previous)  # closing the loop set the default action


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", required=True, help="the server, on a loopback address")
    parser.add_argument("--scene", default="lung_plane")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=4)
    parser.add_argument("--misses", type=int, default=80)
    parser.add_argument("--hit-clients", type=int, default=32)
    parser.add_argument("--period-ms", type=float, default=20.0)
    parser.add_argument("--idle", type=int, default=0, help="idle connections to open")
    parser.add_argument("--idle-rate", type=float, default=2000.0, help="idle connections opened a second")
    args = parser.parse_args()
    loopback(args.url)
    res = run_interruptibly(
        load_for_scene(
            args.url,
            args.scene,
            args.resolution,
            args.spp,
            args.misses,
            args.hit_clients,
            args.period_ms,
            args.idle,
            args.idle_rate,
        )
    )
    print(json.dumps(res.summary()))


def gimap_request(scene: str, eye: tuple[float, float, float], resolution: int, spp: int) -> dict[str, Any]:
    return {
        "scene": scene,
        "camera": {"eye": list(eye), "target": [0.0, 0.5, 0.0]},
        "resolution": resolution,
        "spp": spp,
    }


def hit_request(scene: str, resolution: int, spp: int) -> dict[str, Any]:
    """The one view every hit client asks for (stored first with :func:`store`)."""
    return gimap_request(scene, (0.0, 1.2, 2.0), resolution, spp)


def path_requests(scene: str, views: int, resolution: int, codec: str, spp: int, seed: int) -> list[bytes]:
    """Request bodies of ``views`` GI cameras spread along the fly-through of ``scene`` (a built-in name or a spec
    file, served under its stem), the light at rest, as the cloud client sends them."""
    from baseline_cloudbaking.client import RemoteConfig
    from gicore.paths import camera_path, light_position
    from gicore.scene import load_scene

    spec = load_scene(scene)
    cams = camera_path(spec, views, seed=seed, fov=spec.camera.gi_fov, resolution=resolution)
    remote = RemoteConfig("", Path(scene).stem, resolution, codec, spp, False, False)
    return [remote.body(c, light_position(spec, 0)) for c in cams]


def miss_requests(scene: str, resolution: int, spp: int, n: int, offset: float = 0.0) -> list[dict[str, Any]]:
    """``n`` viewpoints on a circle of radius 2 around the target (0, 0.5, 0), at least 0.14 apart for n <= 80
    (farther than any tolerance, so each is a miss); ``offset`` (radians) turns the circle, giving new views
    against a kept store."""
    angles = np.linspace(0.3, 2 * np.pi - 0.3, n) + offset
    return [gimap_request(scene, (2.0 * np.sin(a), 1.1, 2.0 * np.cos(a)), resolution, spp) for a in angles]


async def store(url: str, body: dict[str, Any]) -> None:
    """Ask for ``body`` once so that it is stored (RuntimeError unless answered 200)."""
    conn = Conn(*loopback(url))
    try:
        status, _, content = await conn.request("POST", "/v1/gimap", json.dumps(body).encode())
    finally:
        conn.close()
    if status != 200:
        raise RuntimeError(f"the hit request was answered {status}: {content[:300]!r}")


async def load_for_scene(
    url: str,
    scene: str,
    resolution: int,
    spp: int,
    misses: int,
    hit_clients: int,
    period_ms: float,
    idle: int = 0,
    idle_rate: float = 2000.0,
) -> LoadResult:
    """Store the hit clients' view, then :func:`run_load` with ``misses`` new viewpoints (:func:`miss_requests`)."""
    hit = hit_request(scene, resolution, spp)
    await store(url, hit)
    offset = (time.time() * 1e3) % 997 * 1e-4  # fresh viewpoints on each run against a kept store
    bodies = miss_requests(scene, resolution, spp, misses, offset)
    return await run_load(
        url, hit, bodies, hit_clients=hit_clients, period_s=period_ms / 1e3, idle=idle, idle_rate=idle_rate
    )


if __name__ == "__main__":
    main()
