"""How ``cloudbaking-server`` stops (docs/architecture.md, Errors): SIGTERM exactly as Ctrl-C, and a requested
stop ends in exit 0 (a service to :func:`gicore.error_policy.entry_point`).

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
import socket
import sys

import uvicorn
from fastapi import FastAPI


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

    def run(self, sockets: list[socket.socket] | None = None) -> None:
        """Serve until stopped (uvicorn raises the signal that stopped it again on its way out); if a render was
        abandoned, end the process at once with exit 0 rather than wait for it."""
        try:
            super().run(sockets)
        finally:
            if self.abandoned:
                print(
                    "cloudbaking-server: stopped; a render still running after the graceful timeout was abandoned "
                    "(its map is not stored)",
                    file=sys.stderr,
                    flush=True,
                )
                sys.stdout.flush()
                os._exit(0)  # the render thread cannot be stopped, and the interpreter would wait for it

    @property
    def abandoned(self) -> bool:
        """A render was still running at the graceful timeout."""
        service = getattr(self.app.state, "service", None)
        return service is not None and service.misses.abandoned
