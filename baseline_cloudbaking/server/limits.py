"""What keeps the server up under floods: a connection cap that drains idle connections (fitted to the
file-descriptor limit, :mod:`gicore.fd_budget`), an idle timeout that also covers slow request heads, and logs
that do not grow with a flood.

uvicorn's ``limit_concurrency`` counts idle connections too, so a flood of idle ones would answer every
real request 503; and uvicorn times out only keep-alive connections that send nothing, not a fresh one,
nor one trickling its head. Here, as nginx reuses keep-alive connections when it runs out: past
``max_connections`` an idle connection is closed for the new one, first the longest-idle of those that
never sent a request (a flood of empty connections then never costs a working client its connection),
then the longest-idle kept-alive one; only when every connection is busy is the new one answered 503
and closed.
Every idle period (a fresh connection, or after a response) must end with a whole request head within
``idle_timeout_s``, else the connection is closed. A request head (request line and headers, each request of
a pipeline on its own, never its body) larger than ``max_head_bytes`` is answered 431 and the connection closed.
With ``write_timeout_s``, a response whose reader takes nothing for that long (writes paused by the transport's
flow control) is dropped and its connection closed: a busy connection is never drained, so stalled readers
would otherwise hold every slot. None of this is a public setting of uvicorn's (``timeout_keep_alive`` and
``h11_max_incomplete_event_size`` are used where they apply): its HTTP protocol classes are subclassed, and
pyproject.toml pins the uvicorn versions the tests ran on.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections import OrderedDict
from typing import Any

import uvicorn
from starlette.types import ASGIApp
from uvicorn.protocols.http.h11_impl import H11Protocol

#: File descriptors kept for everything but client connections (SQLite files of each worker thread,
#: payload reads, the renderer's files, the listening socket): see gicore.fd_budget.
FD_RESERVE = 256
#: What happened to the server's connections, counted in ``/v1/stats``.
COUNTERS = ("connections_accepted", "connections_drained", "connections_timed_out", "connections_refused")
#: How often an idle-connection timer rechecks (the timeout is enforced within this).
_SWEEP_S = 0.25


class ConnectionLimits:
    """The shared state of one server's connections: the idle ones (fresh: no request yet; kept: kept alive
    after a response), each in the order they became idle; those closed here and not yet gone; counters."""

    def __init__(
        self,
        max_connections: int,
        idle_timeout_s: float,
        max_head_bytes: int = 16_384,
        write_timeout_s: float | None = None,
    ) -> None:
        self.max_connections = max_connections
        self.idle_timeout_s = idle_timeout_s
        self.max_head_bytes = max_head_bytes
        self.write_timeout_s = write_timeout_s  # None: a response may wait for its reader for ever
        self.fresh: OrderedDict[H11Protocol, float] = OrderedDict()
        self.kept: OrderedDict[H11Protocol, float] = OrderedDict()
        self.closing: set[H11Protocol] = set()  # closed, connection_lost not yet called: still counted by uvicorn
        self.counters = dict.fromkeys(COUNTERS, 0) | {"heads_too_large": 0, "writes_stalled": 0}
        self._sweeper: asyncio.TimerHandle | None = None

    @property
    def idle(self) -> int:
        return len(self.fresh) + len(self.kept)

    def became_idle(self, conn: H11Protocol, fresh: bool) -> None:
        self.forget(conn)
        (self.fresh if fresh else self.kept)[conn] = time.monotonic()
        if self._sweeper is None:
            self._sweeper = asyncio.get_running_loop().call_later(_SWEEP_S, self._sweep)

    def forget(self, conn: H11Protocol) -> None:
        self.fresh.pop(conn, None)
        self.kept.pop(conn, None)

    def lost(self, conn: H11Protocol) -> None:
        self.forget(conn)
        self.closing.discard(conn)

    def over(self, open_connections: int) -> int:
        """Connections beyond the cap, not counting those already closing."""
        return open_connections - len(self.closing) - self.max_connections

    def close(self, conn: H11Protocol, counter: str) -> None:
        self.closing.add(conn)
        conn.transport.close()
        self.counters[counter] += 1

    def drain_one(self) -> bool:
        """Close the longest-idle fresh connection, else the longest-idle kept one; False when none is idle."""
        for idle in (self.fresh, self.kept):
            while idle:
                conn, _ = idle.popitem(last=False)
                if not busy(conn):
                    self.close(conn, "connections_drained")
                    return True
        return False

    def _sweep(self) -> None:
        """Close connections idle past the timeout: one timer for all, walking the oldest first."""
        self._sweeper = None
        deadline = time.monotonic() - self.idle_timeout_s
        for idle in (self.fresh, self.kept):
            while idle:
                conn, since = next(iter(idle.items()))
                if since > deadline:
                    break
                idle.popitem(last=False)
                if not busy(conn):
                    self.close(conn, "connections_timed_out")
        if self.idle:
            self._sweeper = asyncio.get_running_loop().call_later(_SWEEP_S, self._sweep)


def busy(conn: H11Protocol) -> bool:
    """A request is in progress on ``conn`` (its head has arrived and its response is not complete)."""
    return conn.cycle is not None and not conn.cycle.response_complete


def _answer(status: str, loc: str, msg: str, kind: str, headers: list[tuple[bytes, bytes]]) -> bytes:
    """A whole HTTP response, written before any request was parsed, closing the connection; ``headers``: the
    server's default headers (uvicorn's Date and Server, and those its configuration adds) and any other."""
    body = json.dumps({"detail": [{"loc": [loc], "msg": msg, "type": kind}]}).encode()
    lines = b"".join(name + b": " + value + b"\r\n" for name, value in headers)
    head = f"HTTP/1.1 {status}\r\ncontent-type: application/json\r\nconnection: close\r\ncontent-length: {len(body)}"
    return head.encode() + b"\r\n" + lines + b"\r\n" + body


def http_protocol() -> type[H11Protocol]:
    """uvicorn's HTTP/1.1 protocol: httptools' C parser where it is installed (a hit then costs about a
    third less CPU), else h11 (pure Python)."""
    try:
        from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
    except ImportError:
        return H11Protocol
    return HttpToolsProtocol  # type: ignore[return-value]


#: What a connection refused at the limit is told.
RETRY = (b"retry-after", b"1")
#: What ends a request head.
_HEAD_END = b"\r\n\r\n"


def head_bytes(counted: int, was_in_head: bool, seen: bytes, received: int) -> int:
    """Bytes of the request head still incomplete after a chunk of ``received`` bytes, ``seen`` being the chunk
    with the 3 bytes before it, ``counted`` the head's bytes before it (``was_in_head``: a head was incomplete).
    The incomplete head holds no head end, so it lies after the chunk's last one: counting from there counts at
    most the bytes of a body that ends before it, never a whole earlier request."""
    end = seen.rfind(_HEAD_END)
    if end >= 0:
        return len(seen) - end - len(_HEAD_END)
    return (counted if was_in_head else 0) + received


class WriteTimeout:
    """Before uvicorn's protocol among a protocol's bases: a connection whose writes stay paused (its reader takes
    nothing of what is written) for ``held_to.write_timeout_s`` is dropped, which frees its slot."""

    held_to: ConnectionLimits
    transport: asyncio.Transport
    stall: asyncio.TimerHandle | None = None  # drops the connection if its writes stay paused

    def pause_writing(self) -> None:
        super().pause_writing()  # type: ignore[misc]
        timeout = self.held_to.write_timeout_s
        if timeout is not None and self.stall is None:
            self.stall = asyncio.get_running_loop().call_later(timeout, self.stalled)

    def resume_writing(self) -> None:
        super().resume_writing()  # type: ignore[misc]
        self.unstall()

    def unstall(self) -> None:
        if self.stall is not None:
            self.stall.cancel()
            self.stall = None

    def stalled(self) -> None:
        """Aborted, not closed: a close would wait for the reader to take the rest."""
        self.stall = None
        self.held_to.closing.add(self)  # type: ignore[arg-type]
        self.held_to.counters["writes_stalled"] += 1
        self.transport.abort()


def capped_protocol(limits: ConnectionLimits, base: type[H11Protocol] | None = None) -> type[H11Protocol]:
    """uvicorn's protocol ``base`` (default :func:`http_protocol`) held to ``limits`` (pass it as
    ``uvicorn.Config(http=...)``); both of uvicorn's protocols keep ``connections`` and ``cycle`` alike. The head
    limit is counted here for httptools, whose parser calls ``on_message_begin`` and ``on_headers_complete``
    (it has no limit of its own); h11 keeps its own (``uvicorn.Config(h11_max_incomplete_event_size=...)``)."""

    class CappedProtocol(WriteTimeout, base or http_protocol()):  # type: ignore[misc, valid-type]
        held_to = limits
        in_head = False  # a request head has begun and is not complete
        head_bytes = 0  # of the head in progress, or of the whole head that was too large
        tail = b""  # the last bytes received: a head end may straddle two chunks
        refused = False  # a head was too large: nothing more of this connection is parsed

        def on_message_begin(self) -> None:
            self.in_head = True
            super().on_message_begin()

        def on_headers_complete(self) -> None:
            """A whole head arrived: its size is its request line and headers, as parsed."""
            self.in_head = False
            size = len(self.url) + 16 + sum(len(name) + len(value) + 4 for name, value in self.headers)
            if size > limits.max_head_bytes:  # not passed on to the app; answered 431 after this chunk
                self.refused, self.head_bytes = True, size
                return
            super().on_headers_complete()

        def on_body(self, body: bytes) -> None:
            if not self.refused:
                super().on_body(body)

        def on_message_complete(self) -> None:
            if not self.refused:
                super().on_message_complete()

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            limits.counters["connections_accepted"] += 1
            over = limits.over(len(self.connections))
            while over > 0 and limits.drain_one():
                over -= 1
            if over > 0:  # every other connection is busy: refuse this one
                msg, headers = "the server is at its connection limit", [*self.server_state.default_headers, RETRY]
                transport.write(_answer("503 Service Unavailable", "connection", msg, "overloaded", headers))
                limits.close(self, "connections_refused")
                return
            limits.became_idle(self, fresh=True)

        def data_received(self, data: bytes) -> None:
            if self.refused:
                return
            was_in_head, seen = self.in_head, self.tail + data
            super().data_received(data)  # a chunk is at most the transport's read size
            self.tail = seen[-(len(_HEAD_END) - 1) :]
            if not self.refused:
                self.head_bytes = head_bytes(self.head_bytes, was_in_head, seen, len(data)) if self.in_head else 0
            if self.head_bytes > limits.max_head_bytes and not self.transport.is_closing():
                self.refused = True
                msg = f"the request head exceeds {limits.max_head_bytes} bytes"
                headers = self.server_state.default_headers
                self.transport.write(
                    _answer("431 Request Header Fields Too Large", "headers", msg, "too_large", headers)
                )
                limits.close(self, "heads_too_large")
                return
            if busy(self):
                limits.forget(self)

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                limits.became_idle(self, fresh=False)

        def connection_lost(self, exc: Exception | None) -> None:
            self.unstall()
            limits.lost(self)
            super().connection_lost(exc)

    return CappedProtocol


def uvicorn_config(app: ASGIApp, limits: ConnectionLimits, **options: Any) -> uvicorn.Config:
    """uvicorn's configuration of ``app`` held to ``limits`` (:func:`capped_protocol`; kept-alive connections closed
    after the idle timeout; h11's head limit the same as httptools'), its log lines throttled (:func:`throttle_logs`,
    after uvicorn configured logging); ``options`` set the rest (event loop, log level, backlog, graceful timeout)."""
    config = uvicorn.Config(
        app,
        http=capped_protocol(limits),
        timeout_keep_alive=limits.idle_timeout_s,  # type: ignore[arg-type]  # a float works: call_later
        h11_max_incomplete_event_size=limits.max_head_bytes,
        **options,
    )
    throttle_logs()
    return config


class Throttle(logging.Filter):
    """At most ``burst`` records per message template and logger every ``window_s``; the next record let
    through after a window says how many were held back. A flood of bad requests, refused connections or
    repeated errors then writes a few lines per window instead of one per event."""

    def __init__(self, burst: int = 5, window_s: float = 10.0) -> None:
        super().__init__()
        self.burst = burst
        self.window_s = window_s
        self._seen: dict[tuple[str, str], list[float]] = {}  # key -> [window start, passed, held back]

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, str(record.msg)[:80])  # templates; a formatted message varies only past its start
        now = time.monotonic()
        if len(self._seen) > 1024:  # many distinct messages: forget those whose window is over
            self._seen = {k: v for k, v in self._seen.items() if now - v[0] < self.window_s}
        state = self._seen.get(key)
        if state is None or now - state[0] >= self.window_s:
            held = 0 if state is None else int(state[2])
            self._seen[key] = [now, 1, 0]
            if held:
                record.msg = f"{record.msg} [{held} more like this in the previous {self.window_s:g} s not logged]"
            return True
        if state[1] < self.burst:
            state[1] += 1
            return True
        state[2] += 1
        return False


#: Loggers a flood can drive: uvicorn's errors and access lines, asyncio's accept errors, this server's.
THROTTLED_LOGGERS = ("uvicorn.error", "uvicorn.access", "asyncio", "baseline_cloudbaking")


def throttle_logs(throttle: Throttle | None = None) -> Throttle:
    """Install one :class:`Throttle` on the loggers a flood can drive (after uvicorn configured logging)."""
    throttle = throttle or Throttle()
    for name in THROTTLED_LOGGERS:
        logging.getLogger(name).addFilter(throttle)
    return throttle
