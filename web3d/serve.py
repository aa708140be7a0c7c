"""``gigan-web``'s server: a Starlette app (FastAPI) on uvicorn, held to the cloud-baking server's limits.

:func:`create_app` assembles one router per resource: the page and its files (:mod:`web3d.routes_static`),
``/config.json`` and the forwarding of ``/v1/gimap`` (:mod:`web3d.routes_cloud`), the shadow-map setups
(:mod:`web3d.routes_shadow`). One origin serves everything the page loads, so the browser needs no CORS.

Every response carries ``Cross-Origin-Opener-Policy: same-origin``, ``Cross-Origin-Embedder-Policy: require-corp``
and ``X-Content-Type-Options: nosniff`` (:data:`HEADERS`), the errors that uvicorn and the connection limits write
themselves (400, 431, 503, 500) too: the first two make the page cross-origin isolated, which lets onnxruntime-web's
wasm run with threads (SharedArrayBuffer). A request whose ``Host`` names another server or port (DNS rebinding;
:mod:`baseline_cloudbaking.server.hosts`) is refused 400. ``OPTIONS`` answers 204 with the path's ``Allow``.

uvicorn runs with :mod:`baseline_cloudbaking.server.limits`: at most ``max_connections`` open (an idle one is closed
for a new one), every idle period ends with a whole request head within ``idle_timeout_s`` (a slow or unfinished
head is closed), a head larger than ``max_head_bytes`` is answered 431; a request body must arrive within
``body_timeout_s`` (408), and a reader must take some of its response within ``write_timeout_s``. :class:`WebServer`
serves in this thread (``gigan-web``) or in a background one (benches, tests) on a socket bound first, so port 0
gives a free port known before anything starts.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Collection

import uvicorn
from fastapi import FastAPI, Response
from starlette.routing import BaseRoute, Match, Mount
from starlette.types import ASGIApp, Receive, Scope, Send

from baseline_cloudbaking.server.cli import ACCEPT_BACKLOG
from baseline_cloudbaking.server.hosts import LOOPBACK_HOSTS, HostCheck, allowed_hosts
from baseline_cloudbaking.server.limits import ConnectionLimits, uvicorn_config
from web3d import routes_cloud, routes_shadow, routes_static
from web3d.site import WEB_DIR as WEB_DIR  # where callers look for the page's folder
from web3d.site import Site

#: Headers of every response: uvicorn's default headers, which it writes on its own errors too (an app's
#: middleware would miss those, and a 500 that Starlette's outermost error handler writes).
HEADERS = [
    ("Cross-Origin-Opener-Policy", "same-origin"),
    ("Cross-Origin-Embedder-Policy", "require-corp"),
    ("X-Content-Type-Options", "nosniff"),
]
#: Methods an ``OPTIONS`` answer may list (besides OPTIONS itself).
METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")


class Options:
    """ASGI middleware: ``OPTIONS`` answered 204 with the methods the path takes (404 for a path nothing serves)."""

    def __init__(self, app: ASGIApp, routes: list[BaseRoute]) -> None:
        self.app = app
        self.routes = routes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "OPTIONS":
            await self.app(scope, receive, send)
            return
        allowed = allowed_methods(self.routes, scope)
        headers = {"Allow": ", ".join(sorted(allowed | {"OPTIONS"}))}
        await Response(status_code=204 if allowed else 404, headers=headers)(scope, receive, send)


def create_app(site: Site, hosts: Collection[str] = LOOPBACK_HOSTS, port: int | None = None) -> FastAPI:
    """The app serving ``site``; ``hosts``: the ``Host`` names it answers, ``port``: the one port a ``Host`` may
    name (None: any)."""
    app = FastAPI(docs_url=None, redoc_url=None, openapi_url=None, lifespan=routes_cloud.lifespan)
    app.state.site = site
    app.include_router(routes_cloud.router)
    app.include_router(routes_shadow.router)
    app.router.routes.extend(routes_static.routes(site.assets, site.web))
    app.add_middleware(Options, routes=app.router.routes)
    app.add_middleware(HostCheck, names=hosts, port=port)
    return app


def allowed_methods(routes: list[BaseRoute], scope: Scope) -> set[str]:
    """The methods the first route for ``scope``'s path takes (a static folder: GET and HEAD)."""
    for route in routes:
        if isinstance(route, Mount):  # a static folder: every method matches
            if route.matches(scope)[0] is not Match.NONE:
                return {"GET", "HEAD"}
            continue
        methods = {m for m in METHODS if route.matches({**scope, "method": m})[0] is Match.FULL}
        if methods:
            return methods
    return set()


class _Uvicorn(uvicorn.Server):
    """uvicorn's server that tells ``app`` when a stop begins (``app.state.stopping``, made by its lifespan)."""

    def __init__(self, config: uvicorn.Config, app: FastAPI) -> None:
        super().__init__(config)
        self.app = app

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        stopping = getattr(self.app.state, "stopping", None)  # absent when the app's startup failed
        if stopping is not None:
            stopping.set()
        await super().shutdown(sockets)


class WebServer:
    """The server for ``site`` on ``host:port`` (port 0: a free one); :attr:`url` is its address as soon as it
    is made. ``site`` may come later (:meth:`attach`), so that the address is taken before anything is
    exported. Use :meth:`start` (a background thread; :meth:`close` stops it) or :meth:`serve_forever`."""

    def __init__(self, site: Site | None, host: str = "127.0.0.1", port: int = 0) -> None:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]  # AF_INET6 for [::1]
        self.socket = socket.create_server((host, port), family=family, backlog=ACCEPT_BACKLOG)
        self.host = host
        self.site = site
        self._server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None

    def attach(self, site: Site) -> None:
        self.site = site

    @property
    def url(self) -> str:
        host, port = self.socket.getsockname()[:2]
        return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"

    def _uvicorn(self) -> uvicorn.Server:
        assert self.site is not None, "attach a site first"
        settings = self.site.settings
        limits = ConnectionLimits(
            settings.max_connections, settings.idle_timeout_s, settings.max_head_bytes, settings.write_timeout_s
        )
        app = create_app(self.site, allowed_hosts(self.host, self.socket), self.socket.getsockname()[1])
        config = uvicorn_config(
            app,
            limits,
            log_level="warning",
            access_log=False,
            headers=HEADERS,
            backlog=ACCEPT_BACKLOG,
            # after the app's own deadline, which answers a request still forwarded 503 (routes_cloud.Stopping)
            timeout_graceful_shutdown=settings.graceful_timeout_s + 1,
        )
        self._server = _Uvicorn(config, app)
        return self._server

    def start(self) -> WebServer:
        """Serve in a background thread; returns once it accepts requests."""
        server = self._uvicorn()
        self._thread = threading.Thread(target=server.run, kwargs={"sockets": [self.socket]}, daemon=True)
        self._thread.start()
        while not server.started and self._thread.is_alive():
            self._thread.join(0.01)
        if not server.started:
            raise RuntimeError(f"the viewer's server at {self.url} did not start")
        return self

    def serve_forever(self, announce: Callable[[], None]) -> None:
        """Serve in this thread until SIGINT or SIGTERM (uvicorn finishes the requests in flight within the
        graceful timeout, then raises the signal again); ``announce`` runs once uvicorn has started. Before that,
        uvicorn is still importing its protocols and has not taken over the signals: a Ctrl-C that lands in an
        import's lock clean-up is swallowed there ("Exception ignored"), and the viewer would serve on, so a
        "serving" line printed earlier would invite a stop that can be lost."""
        server = self._uvicorn()

        def when_started() -> None:
            while not (server.started or server.should_exit):
                time.sleep(0.01)
            if server.started:
                announce()

        threading.Thread(target=when_started, name="announce", daemon=True).start()
        try:
            server.run(sockets=[self.socket])
        finally:
            self.socket.close()

    def close(self) -> None:
        if self._server is not None and self._thread is not None:
            self._server.should_exit = True
            self._thread.join()
        self.socket.close()

    def __enter__(self) -> WebServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
