"""How ``cloudbaking-server`` stops: SIGTERM exactly as Ctrl-C (SIGINT), a requested stop that ends in exit 0.

On either signal uvicorn stops taking connections and waits for the requests in progress;
:class:`StoppingServer` first tells the map service (:meth:`~baseline_cloudbaking.server.service.MapService.stop`),
so that misses still waiting are answered 503 at once and the miss being rendered has the graceful timeout to
finish, be stored and be answered. Then the app's lifespan closes the GI tree (after an insert in progress).
A render still running after the timeout cannot be cut short: it is abandoned, its map not stored, and the
process ends without waiting for it. A second Ctrl-C stops at once (uvicorn's force exit); the GI tree is
crash-safe, so that too loses no stored map.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
from types import FrameType, TracebackType
from typing import Any

import uvicorn
from fastapi import FastAPI

#: The signals that ask the server to stop (uvicorn handles both alike while it runs).
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


class StopRequested(Exception):
    """SIGTERM or SIGINT before or after uvicorn ran (uvicorn raises the signal it caught again once it has
    stopped, which lands here)."""


def _raise_stop(signum: int, frame: FrameType | None) -> None:
    raise StopRequested


class StoppingServer(uvicorn.Server):
    """uvicorn's server that tells ``app``'s map service when a stop begins."""

    def __init__(self, config: uvicorn.Config, app: FastAPI) -> None:
        super().__init__(config)
        self.app = app

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        service = getattr(self.app.state, "service", None)  # absent when the app's startup failed
        if service is not None:
            service.stop()
        await super().shutdown(sockets)

    @property
    def abandoned(self) -> bool:
        """A render was still running at the graceful timeout."""
        service = getattr(self.app.state, "service", None)
        return service is not None and service.misses.abandoned


class RequestedStop:
    """A context in which SIGTERM and SIGINT end the run normally (the ``with`` block is left, exit 0 follows):
    before uvicorn runs, at once; while it runs, once it has stopped. Set ``server`` when it starts: if a render
    was abandoned, the process ends on leaving the block rather than wait for it."""

    def __init__(self) -> None:
        self.server: StoppingServer | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> RequestedStop:
        self._previous = {sig: signal.signal(sig, _raise_stop) for sig in STOP_SIGNALS}
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> bool:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        if kind is not None and not issubclass(kind, StopRequested):
            return False
        if self.server is not None and self.server.abandoned:
            print(
                "cloudbaking-server: stopped; a render still running after the graceful timeout was abandoned "
                "(its map is not stored)",
                file=sys.stderr,
                flush=True,
            )
            sys.stdout.flush()
            os._exit(0)  # the render thread cannot be stopped, and the interpreter would wait for it
        return True
