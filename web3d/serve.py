"""``gigan-web``'s server: the page, its modules and assets, and ``/v1/gimap`` forwarded to cloud baking.

One origin serves everything the page loads, so the browser needs no CORS: the cloud canvas's
``fetch("/v1/gimap")`` comes here and is forwarded, body and content type unchanged, to the configured
cloud-baking server (or the ``network-sim proxy`` in front of it); the response's bytes, status, content
type and ``X-GIMap-Hit`` go back as they came. With no upstream configured, ``/v1/gimap`` answers 503 and
the page shows the cloud side as off.

Every response carries ``Cross-Origin-Opener-Policy: same-origin`` and ``Cross-Origin-Embedder-Policy:
require-corp``: they make the page cross-origin isolated, which is what lets onnxruntime-web's wasm run
with threads (SharedArrayBuffer). Files are served only from three roots (``web3d/static/`` without its
``node_modules``, the two npm packages' distribution folders, the exported assets); any other path is 404.
"""

from __future__ import annotations

import json
import threading
import urllib.error
import urllib.request
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

#: The page's folder (``web3d/static/`` at the repository root).
WEB_DIR = Path(__file__).resolve().parent / "static"
#: npm files the page imports, by URL prefix: only these folders of ``web3d/static/node_modules`` are served.
NPM_ROOTS = {
    "/npm/onnxruntime-web/": Path("onnxruntime-web/dist"),
    "/npm/fzstd/": Path("fzstd/esm"),
}
MEDIA = {
    ".html": "text/html; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".mjs": "text/javascript; charset=utf-8",
    ".json": "application/json",
    ".wasm": "application/wasm",
    ".bin": "application/octet-stream",
    ".onnx": "application/octet-stream",
    ".css": "text/css; charset=utf-8",
    ".png": "image/png",
}
#: Largest request body forwarded (the cloud server refuses more than 4 KiB anyway).
MAX_BODY = 1 << 16
ISOLATION = {"Cross-Origin-Opener-Policy": "same-origin", "Cross-Origin-Embedder-Policy": "require-corp"}


@dataclass(frozen=True)
class Site:
    """What the server serves: the exported ``assets`` folder, the page's ``config`` (``/config.json``) and
    the cloud-baking ``upstream`` URL (None: the cloud side is off)."""

    assets: Path
    config: dict[str, Any]
    upstream: str | None = None
    web: Path = WEB_DIR
    #: Seconds a forwarded request may take (a miss path-traces on the server).
    timeout_s: float = 120.0

    def resolve(self, url_path: str) -> Path | None:
        """The file behind ``url_path``, or None when it is outside the served roots or missing."""
        roots: list[tuple[str, Path]] = [("/assets/", self.assets)]
        roots += [(prefix, self.web / "node_modules" / sub) for prefix, sub in NPM_ROOTS.items()]
        roots += [("/", self.web)]
        for prefix, root in roots:
            if url_path.startswith(prefix):
                rel = url_path[len(prefix) :] or "index.html"
                path = (root / rel).resolve()
                root = root.resolve()
                if root not in path.parents or (prefix == "/" and "node_modules" in path.relative_to(root).parts):
                    return None
                return path if path.is_file() else None
        return None


def _handler(site: Site) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 -- the stdlib's signature
            pass  # a request line per file is noise; errors reach the page and the bench

        def _send(self, status: int, body: bytes, media: str, extra: dict[str, str] | None = None) -> None:
            self.send_response(status)
            headers = {**ISOLATION, "Content-Type": media, "Cache-Control": "no-store", **(extra or {})}
            for key, value in headers.items():
                self.send_header(key, value)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            try:
                self.wfile.write(body)
            except (BrokenPipeError, ConnectionResetError):  # the page went away (closed mid-request)
                self.close_connection = True

        def do_GET(self) -> None:
            path = self.path.split("?", 1)[0]
            if path == "/config.json":
                self._send(200, json.dumps(site.config).encode(), MEDIA[".json"])
                return
            file = site.resolve(path)
            if file is None:
                self._send(404, b"not found", "text/plain")
                return
            self._send(200, file.read_bytes(), MEDIA.get(file.suffix, "application/octet-stream"))

        def do_POST(self) -> None:
            if self.path != "/v1/gimap":
                self._send(404, b"not found", "text/plain")
                return
            length = int(self.headers.get("Content-Length") or 0)
            if not 0 < length <= MAX_BODY:
                self._send(413, b"request body missing or too large", "text/plain")
                return
            body = self.rfile.read(length)
            if site.upstream is None:
                self._send(503, b"no cloud-baking server configured (gigan-web --server URL)", "text/plain")
                return
            request = urllib.request.Request(
                site.upstream.rstrip("/") + "/v1/gimap",
                data=body,
                method="POST",
                headers={"Content-Type": self.headers.get("Content-Type", "application/json")},
            )
            try:
                with urllib.request.urlopen(request, timeout=site.timeout_s) as response:
                    status, data, headers = response.status, response.read(), response.headers
            except urllib.error.HTTPError as err:  # the server's own error (422, 409, ...) goes back as it is
                status, data, headers = err.code, err.read(), err.headers
            except (urllib.error.URLError, TimeoutError, ConnectionError) as err:
                self._send(502, f"cloud-baking server {site.upstream}: {err}".encode(), "text/plain")
                return
            extra = {"X-GIMap-Hit": headers["X-GIMap-Hit"]} if headers.get("X-GIMap-Hit") else {}
            self._send(status, data, headers.get("Content-Type", "application/octet-stream"), extra)

    return Handler


class WebServer:
    """A threaded HTTP server for ``site`` on ``host:port`` (port 0: a free one); :attr:`url` is its address.
    ``site`` may come later (:meth:`attach`), so that the address is taken before anything is exported. Use
    :meth:`start` (a background thread) or :meth:`serve_forever`."""

    def __init__(self, site: Site | None, host: str = "127.0.0.1", port: int = 0) -> None:
        self.httpd = ThreadingHTTPServer((host, port), BaseHTTPRequestHandler)
        self.httpd.daemon_threads = True
        self.site: Site | None = None
        if site is not None:
            self.attach(site)
        self._thread: threading.Thread | None = None

    def attach(self, site: Site) -> None:
        self.site = site
        self.httpd.RequestHandlerClass = _handler(site)

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host}:{port}"

    def start(self) -> WebServer:
        self._thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Serve in this thread until interrupted; requests in flight (daemon threads) are dropped with the
        process: the page retries, and a GI map the cloud server was making is stored there regardless."""
        try:
            self.httpd.serve_forever()
        finally:
            self.httpd.server_close()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()

    def __enter__(self) -> WebServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
