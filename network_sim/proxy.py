"""The link-emulating TCP proxy: every byte between a client and its upstream crosses :mod:`network_sim.link`
(docs/architecture.md, Proxy).

One asyncio event loop; per client connection one upstream connection, TCP_NODELAY on both legs, and per
direction a pipe that offers what it reads to the link model (:meth:`Stream.send`) and writes each chunk at the
release time the model gave it (``loop.call_at`` on absolute deadlines; :class:`PreciseSelector` waits with
microsecond timeouts, so a timer fires within tens of microseconds without busy-waiting); the optional
per-chunk log has ``sent_s`` next to ``release_s``. Rate, queue and delay are shared by a direction's
connections, as on one bottleneck link; each connection has its own FIFO, window and loss draws. A pipe stops
reading its sender while the model has not admitted what it holds, the receiver's buffer is full or all
connections together hold :data:`MAX_HELD_BYTES`: it never drops stream bytes. At most ``max_connections``
client connections are kept (one more is closed on accept; refusals reported at most once per 10 s), and a
connection that moved fewer than ``idle_min_bytes`` in ``idle_timeout_s`` (checks that find its bytes due in the
link skip it) is closed on both sides, so held or trickling sockets give their slots back. Every run can keep a
lateness summary (write time minus model release, :class:`~network_sim.chunklog.LatenessSummary`), written at
exit. SIGTERM/SIGINT: stop accepting, close every connection with FIN, write the log and the summary, exit 0.
Not emulated: the TCP handshake, congestion control, loss bursts.
"""

from __future__ import annotations

import asyncio
import math
import select
import selectors
import signal
import socket
import sys
from collections import deque
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path

from gicore.error_policy import UserError
from gicore.fd_budget import connection_budget
from network_sim.chunklog import ChunkLog, LatenessSummary, lateness_report, write_lateness
from network_sim.link import DOWN, UP, Chunk, Link, LinkConfig, Stream

#: A timer that fires this close before its deadline counts as on time (asyncio runs handles due within
#: its clock resolution).
_EARLY_S = 1e-6
#: How long the proxy waits for an upstream connection to be accepted.
CONNECT_TIMEOUT_S = 5.0
#: Default cap on concurrent client connections.
MAX_CONNECTIONS = 1024
#: File descriptors kept for everything but proxied connections (listening socket, log, stdio); each proxied
#: connection takes two (client and upstream legs).
FD_RESERVE = 64
#: Refused connections are reported at most this often, s.
REFUSAL_REPORT_S = 10.0
#: Default idle timeout, s: as a carrier NAT forgets an idle TCP flow after minutes, and longer than any
#: client here waits for an answer (a miss path-traced in silence is the client's to give up on, not the link's).
IDLE_TIMEOUT_S = 300.0
#: Idle connections are looked for this many times per idle timeout (one is closed within 1.25 timeouts).
IDLE_CHECKS = 4
#: Default least bytes a connection must move (read plus written, both legs) per idle timeout not to be idle. A
#: request and its answer move more; a client trickling a byte every 1.5 s (400 bytes per 300 s, 800 echoed)
#: does not, so it cannot hold a slot, and holding all 1024 slots at the defaults takes 3.5 kB/s.
IDLE_MIN_BYTES = 1024
#: Most stream bytes held inside the emulated link, all connections together: past it no sender is read until
#: half of it has been delivered (a 1024-connection flood through a long unshaped delay would otherwise hold
#: every connection's window, 3 MiB each way).
MAX_HELD_BYTES = 256 * 2**20


class PreciseSelector(selectors.EpollSelector):
    """Epoll with microsecond timeouts.

    ``epoll_wait`` takes whole milliseconds and Python rounds up, so asyncio timers would fire up to 1 ms
    late. Waiting first with ``select()`` on the epoll descriptor itself (readable when any registered
    socket is ready; ``select`` timeouts have microsecond resolution), then collecting the events with a
    zero timeout, keeps epoll's scalability and makes sleeps precise.
    """

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        if timeout is not None and timeout > 0:
            try:
                select.select([self.fileno()], [], [], timeout)
            except ValueError:  # descriptor beyond FD_SETSIZE: fall back to millisecond epoll
                return super().select(timeout)
            timeout = 0
        return super().select(timeout)


def new_event_loop() -> asyncio.AbstractEventLoop:
    """An asyncio loop that waits with :class:`PreciseSelector`."""
    return asyncio.SelectorEventLoop(PreciseSelector())


class _Side(asyncio.Protocol):
    """One TCP leg of a proxied connection (``UP`` names the client's leg: it feeds the up pipe)."""

    def __init__(self, conn: _Connection, feeds: str) -> None:
        self.conn = conn
        self.feeds = feeds
        self.transport: asyncio.Transport | None = None
        self.lost = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.conn.side_connected(self)

    def data_received(self, data: bytes) -> None:
        self.conn.moved += len(data)
        self.conn.pipes[self.feeds].feed(data)

    def eof_received(self) -> bool:
        self.conn.pipes[self.feeds].end()
        return True  # keep the transport open: the other direction may still be sending

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = True
        self.conn.side_lost(self)

    def pause_writing(self) -> None:
        self.conn.pipe_into(self).hold("receiver")

    def resume_writing(self) -> None:
        self.conn.pipe_into(self).unhold("receiver")


class _Pipe:
    """One direction of one connection: read from ``src``, offer to the model, write to ``dst`` on time."""

    def __init__(self, proxy: Proxy, stream: Stream, src: _Side, dst: _Side) -> None:
        self.proxy = proxy
        self.stream = stream
        self.src = src
        self.dst = dst
        self.max_chunk = stream.direction.max_chunk
        self.waiting: deque[bytes] = deque()  # read, not yet admitted by the model
        self.pending: deque[tuple[Chunk, bytes]] = deque()  # admitted, waiting for release
        self.holds: set[str] = set()
        self.offer_timer: asyncio.TimerHandle | None = None
        self.flush_timer: asyncio.TimerHandle | None = None
        self.eof = False
        self.done = False

    # -- reading --------------------------------------------------------------------------------------
    def hold(self, reason: str) -> None:
        if not self.holds and self.src.transport is not None and not self.src.lost:
            self.src.transport.pause_reading()
        self.holds.add(reason)

    def unhold(self, reason: str) -> None:
        if reason in self.holds:
            self.holds.discard(reason)
            if not self.holds and self.src.transport is not None and not self.src.lost:
                self.src.transport.resume_reading()
            if reason == "receiver":  # what came due meanwhile is written now
                self._schedule_flush(self.proxy.now())

    def feed(self, data: bytes) -> None:
        self.proxy.take(self, len(data))
        if len(data) <= self.max_chunk:
            self.waiting.append(data)
        else:
            view = memoryview(data)
            self.waiting.extend(bytes(view[i : i + self.max_chunk]) for i in range(0, len(data), self.max_chunk))
        if self.offer_timer is None:
            self._offer()

    def _offer(self) -> None:
        """Offer waiting chunks to the model while it admits them now; otherwise hold the sender."""
        self.offer_timer = None
        now = self.proxy.now()
        while self.waiting:
            size = len(self.waiting[0])
            opens = self.stream.window_open_at(size, now)
            if opens > now + _EARLY_S:
                self._hold_until(opens)
                break
            chunk = self.stream.send(size, now)
            self.pending.append((chunk, self.waiting.popleft()))
            if chunk.admitted > now + _EARLY_S:  # the queue was full: the sender waits until admission
                self._hold_until(chunk.admitted)
                break
        else:
            self.unhold("model")
        self._schedule_flush(now)
        self._maybe_finish()

    def _hold_until(self, t: float) -> None:
        self.hold("model")
        if math.isfinite(t):
            self.offer_timer = self.proxy.call_at(t, self._offer)

    def end(self) -> None:
        """The sender closed its side (EOF)."""
        self.eof = True
        self._maybe_finish()

    # -- writing --------------------------------------------------------------------------------------
    def _schedule_flush(self, now: float) -> None:
        if self.flush_timer is not None or not self.pending or "receiver" in self.holds:
            return  # a receiver that reads nothing gets nothing more: the bytes stay counted in the link
        head = self.pending[0][0].release
        if head <= now + _EARLY_S:
            self._flush()
        elif math.isfinite(head):
            self.flush_timer = self.proxy.call_at(head, self._flush)

    def _flush(self) -> None:
        self.flush_timer = None
        now = self.proxy.now()
        transport = self.dst.transport
        while self.pending and self.pending[0][0].release <= now + _EARLY_S and "receiver" not in self.holds:
            chunk, data = self.pending.popleft()
            self.proxy.give(len(data))
            if transport is not None and not self.dst.lost and not transport.is_closing():  # closing: lost soon
                transport.write(data)  # may pause writing: the receiver hold ends this loop
                self.src.conn.moved += len(data)
            self.proxy.logged(chunk, now)
        self._schedule_flush(now)
        self._maybe_finish()

    def _maybe_finish(self) -> None:
        """Forward the EOF once everything before it is delivered; give up on bytes that can never be."""
        if self.done or not self.eof:
            return
        # never deliverable: the next chunk is released at infinity, or the model will never admit more
        never = bool(self.pending) and not math.isfinite(self.pending[0][0].release)
        never = never or (
            not self.pending and bool(self.waiting) and "model" in self.holds and self.offer_timer is None
        )
        if not never and (self.pending or self.waiting):
            return
        if not never and self.dst.transport is not None and not self.dst.lost and self.dst.transport.can_write_eof():
            with suppress(OSError):  # the receiver reset and its connection_lost is yet to come: it ends the pipe
                self.dst.transport.write_eof()
        self.discard()
        self.done = True
        self.proxy.connection_step(self.src.conn)

    def discard(self) -> None:
        """Drop what is still inside the emulated link (shutdown, a vanished receiver, a dead link)."""
        for timer in (self.offer_timer, self.flush_timer):
            if timer is not None:
                timer.cancel()
        self.offer_timer = self.flush_timer = None
        for chunk, _ in self.pending:
            self.proxy.logged(chunk, None)
        self.proxy.give(sum(len(data) for _, data in self.pending) + sum(map(len, self.waiting)))
        self.pending.clear()
        self.waiting.clear()


class _Connection:
    """A client connection, its upstream connection and the two pipes between them."""

    def __init__(self, proxy: Proxy, conn_id: int) -> None:
        self.proxy = proxy
        self.id = conn_id
        self.client = _Side(self, UP)
        self.upstream = _Side(self, DOWN)
        link = proxy.link
        self.pipes = {
            UP: _Pipe(proxy, link.stream(conn_id, UP), self.client, self.upstream),
            DOWN: _Pipe(proxy, link.stream(conn_id, DOWN), self.upstream, self.client),
        }
        self.closed = False
        #: Bytes read from or written to either leg since the last idle check that found none of them in the link,
        #: and in each interval between the last such checks (a connection's first one is partial).
        self.moved = 0
        self.intervals: deque[int] = deque(maxlen=IDLE_CHECKS + 1)

    def idle(self, min_bytes: int) -> bool:
        """At an idle check: whether the connection moved fewer than ``min_bytes`` in its last :data:`IDLE_CHECKS`
        whole intervals (an idle timeout) between checks that found none of its bytes due in the link. A check
        that finds bytes due skips it, and what it moves meanwhile counts toward the next interval: a round trip
        longer than the timeout is no idleness."""
        if any(p.offer_timer is not None or p.flush_timer is not None for p in self.pipes.values()):
            return False
        self.intervals.append(self.moved)
        self.moved = 0
        # younger than one idle timeout of whole intervals: not judged yet
        return len(self.intervals) > IDLE_CHECKS and sum(self.intervals) - self.intervals[0] < min_bytes

    def pipe_into(self, side: _Side) -> _Pipe:
        return self.pipes[DOWN] if side is self.client else self.pipes[UP]

    def side_connected(self, side: _Side) -> None:
        if side is self.client:
            self.pipes[UP].hold("connect")  # nothing can be written upstream before it is connected
            self.proxy.spawn(self._connect())
        elif self.closed and side.transport is not None:  # the client went away while the upstream connected
            side.transport.close()
        else:
            self.pipes[UP].unhold("connect")

    async def _connect(self) -> None:
        host, port = self.proxy.upstream
        try:
            await asyncio.wait_for(
                asyncio.get_running_loop().create_connection(lambda: self.upstream, host, port), CONNECT_TIMEOUT_S
            )
        except (TimeoutError, OSError) as exc:
            print(
                f"network-sim proxy: connection {self.id}: upstream {host}:{port} unreachable "
                f"({exc or 'timeout'}); closing the client",
                file=sys.stderr,
                flush=True,
            )
            self.close()

    def side_lost(self, side: _Side) -> None:
        self.pipe_into(side).discard()
        self.pipe_into(side).done = True
        feeding = self.pipes[side.feeds]
        if not feeding.eof:
            feeding.end()
        self.proxy.connection_step(self)

    def close(self) -> None:
        """Close both legs (FIN after what the kernel already holds) and drop what the link still holds."""
        if self.closed:
            return
        self.closed = True
        for pipe in self.pipes.values():
            pipe.discard()
            pipe.done = True
        for side in (self.client, self.upstream):
            if side.transport is not None and not side.lost:
                side.transport.close()
        self.proxy.forget(self)


class _Refused(asyncio.Protocol):
    """A client connection beyond the cap: closed at once."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        transport.close()


class Proxy:
    """Accepts client connections (at most ``max_connections`` at once) and proxies each through the shared
    :class:`Link` model."""

    def __init__(
        self,
        config: LinkConfig,
        upstream: tuple[str, int],
        log: ChunkLog | None = None,
        max_connections: int = MAX_CONNECTIONS,
        idle_timeout_s: float = IDLE_TIMEOUT_S,
        max_held_bytes: int = MAX_HELD_BYTES,
        idle_min_bytes: int = IDLE_MIN_BYTES,
        lateness: LatenessSummary | None = None,
    ) -> None:
        self.loop = asyncio.get_running_loop()
        self.link = Link(config)
        self.upstream = upstream
        self.log = log
        self.max_connections = max_connections
        self.origin = self.loop.time()
        self.connections: dict[int, _Connection] = {}
        self._next_id = 0
        self._tasks: set[asyncio.Task[None]] = set()
        self.refused = 0
        self._refused_reported = 0
        self._report: asyncio.TimerHandle | None = None
        self.idle_timeout_s, self.idle_min_bytes = idle_timeout_s, idle_min_bytes
        self.lateness = lateness
        #: Set by SIGTERM/SIGINT or by a fatal error (then in :attr:`error`): the proxy shuts down.
        self.stopped = asyncio.Event()
        self.error: UserError | None = None
        #: Stream bytes read and not yet written or dropped, and the pipes not read until they shrink.
        self.held_bytes, self.max_held_bytes = 0, max_held_bytes
        self._short_of_memory: set[_Pipe] = set()
        self._idle_check = self.loop.call_later(idle_timeout_s / IDLE_CHECKS, self.close_idle)

    def now(self) -> float:
        """The model's clock: seconds since the origin."""
        return self.loop.time() - self.origin

    def call_at(self, t: float, callback: object) -> asyncio.TimerHandle:
        return self.loop.call_at(self.origin + t, callback)  # type: ignore[arg-type]

    def spawn(self, coro: object) -> None:
        task = self.loop.create_task(coro)  # type: ignore[arg-type]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def accept(self) -> _Side | _Refused:
        """Protocol factory of the listening socket: a new connection's client leg, or a refusal at the cap."""
        if len(self.connections) >= self.max_connections:
            self.refused += 1
            if self._report is None:
                self._report = self.loop.call_later(
                    0 if self._refused_reported == 0 else REFUSAL_REPORT_S, self.report_refusals
                )
            return _Refused()
        conn = _Connection(self, self._next_id)
        self._next_id += 1
        self.connections[conn.id] = conn
        return conn.client

    def report_refusals(self) -> None:
        """One stderr line for the refusals since the last one."""
        if self._report is not None:
            self._report.cancel()
        self._report = None
        new, self._refused_reported = self.refused - self._refused_reported, self.refused
        print(
            f"network-sim proxy: {new} connection(s) refused at the cap of {self.max_connections} "
            f"({self.refused} in all; reported at most every {REFUSAL_REPORT_S:g} s)",
            file=sys.stderr,
            flush=True,
        )

    def take(self, pipe: _Pipe, nbytes: int) -> None:
        """``pipe`` read ``nbytes`` into the link; past the bound it is not read again until :meth:`give`."""
        self.held_bytes += nbytes
        if self.held_bytes > self.max_held_bytes:
            pipe.hold("memory")
            self._short_of_memory.add(pipe)

    def give(self, nbytes: int) -> None:
        """``nbytes`` left the link (written or dropped); at half the bound every held sender is read again."""
        self.held_bytes -= nbytes
        if self._short_of_memory and self.held_bytes <= self.max_held_bytes // 2:
            pipes, self._short_of_memory = self._short_of_memory, set()
            for pipe in pipes:
                pipe.unhold("memory")

    def logged(self, chunk: Chunk, sent: float | None) -> None:
        """Count a chunk's lateness and log it; a log that cannot be written any more stops the proxy with that
        error."""
        if self.lateness is not None:
            self.lateness.add(chunk.direction, None if sent is None else sent - chunk.release)
        if self.log is None:
            return
        try:
            self.log.row(chunk, sent)
        except UserError as exc:
            with suppress(UserError):  # closed now, so that the unwritable rest is not flushed again at exit
                self.log.close()
            self.log, self.error = None, exc
            self.stopped.set()

    def connection_step(self, conn: _Connection) -> None:
        """Close a connection once both directions are finished."""
        if all(p.done for p in conn.pipes.values()):
            conn.close()

    def forget(self, conn: _Connection) -> None:
        self.connections.pop(conn.id, None)
        self.link.forget(conn.id)

    def close_idle(self) -> None:
        """Close both legs of every connection idle for the idle timeout; check again a fraction of it later."""
        for conn in [c for c in self.connections.values() if c.idle(self.idle_min_bytes)]:
            conn.close()
        self._idle_check = self.loop.call_later(self.idle_timeout_s / IDLE_CHECKS, self.close_idle)

    def close_all(self) -> None:
        self._idle_check.cancel()
        for conn in list(self.connections.values()):
            conn.close()

    def shut_down(self, lateness_path: Path | None) -> None:
        """Close every connection, report the refusals not yet reported, close the log and write the lateness
        summary to ``lateness_path``; the first failure is kept in :attr:`error`."""
        self.close_all()
        if self.refused > self._refused_reported:
            self.report_refusals()
        for finish in (self._close_log, lambda: self._write_lateness(lateness_path)):
            try:
                finish()
            except UserError as exc:
                self.error = self.error or exc

    def _close_log(self) -> None:
        if self.log is not None:
            self.log.close()

    def _write_lateness(self, path: Path | None) -> None:
        if path is not None and self.lateness is not None:
            write_lateness(path, lateness_report(self.lateness, self.link.config.rtt_s * 1e3))


def check_upstream(upstream: tuple[str, int], timeout_s: float = 3.0) -> None:
    """Fail with one line if nothing accepts connections at ``upstream``."""
    host, port = upstream
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as exc:
        raise UserError(
            f"--upstream {host}:{port} is unreachable ({exc.strerror or exc})",
            "start the server first, or fix --upstream",
        ) from None


@dataclass(frozen=True)
class Settings:
    """What ``network-sim proxy`` takes beside its link and addresses (the CLI's options of the same names)."""

    #: The per-chunk CSV log (:class:`~network_sim.chunklog.ChunkLog`).
    log: Path | None = None
    #: The lateness summary, JSON written at exit (:func:`~network_sim.chunklog.read_lateness`).
    lateness: Path | None = None
    max_connections: int = MAX_CONNECTIONS
    idle_timeout_s: float = IDLE_TIMEOUT_S
    idle_min_bytes: int = IDLE_MIN_BYTES


async def serve(config: LinkConfig, listen: tuple[str, int], upstream: tuple[str, int], settings: Settings) -> None:
    """Run the proxy until SIGTERM or SIGINT (or until its log fails: that UserError is raised after the
    shutdown); prints ``listening on HOST:PORT`` first."""
    loop = asyncio.get_running_loop()
    log = ChunkLog(settings.log) if settings.log is not None else None
    lateness = None
    if settings.lateness is not None:  # a summary an earlier run left must not pass for this one's
        settings.lateness.unlink(missing_ok=True)
        lateness = LatenessSummary()
    budget, _ = connection_budget(settings.max_connections, FD_RESERVE, 2, who="network-sim proxy: --max-connections")
    proxy = Proxy(config, upstream, log, budget, settings.idle_timeout_s, idle_min_bytes=settings.idle_min_bytes,
                  lateness=lateness)  # fmt: skip
    for sig in (signal.SIGTERM, signal.SIGINT):  # before announcing the port: a signal right after it must stop cleanly
        loop.add_signal_handler(sig, proxy.stopped.set)
    try:
        server = await loop.create_server(proxy.accept, listen[0], listen[1])
    except OSError as exc:
        raise UserError(
            f"--listen {listen[0]}:{listen[1]}: cannot listen ({exc.strerror or exc})", "pick a free port, or 0 for any"
        ) from None
    host, port = server.sockets[0].getsockname()[:2]
    print(f"listening on {host}:{port}", flush=True)
    print(f"clock origin {proxy.origin!r} (CLOCK_MONOTONIC s; log and trace times count from it)", flush=True)
    try:
        await proxy.stopped.wait()
    finally:
        server.close()
        proxy.shut_down(settings.lateness)
    if proxy.error is not None:
        raise proxy.error


def run(config: LinkConfig, listen: tuple[str, int], upstream: tuple[str, int], settings: Settings) -> None:
    """Check the upstream, then proxy on a precise event loop until signalled."""
    check_upstream(upstream)
    loop = new_event_loop()
    try:
        loop.run_until_complete(serve(config, listen, upstream, settings))
    finally:
        loop.close()
