"""One GI-map request (:func:`fetch`: the HTTP exchange and the payload's decode) and where it runs
(docs/architecture.md, Data flow of a cloud-baking frame).

A client that renders its frames in the same process as its requests pays for the frame thread in every request:
CPython runs one thread at a time, and a GL frame holds the interpreter for most of its time, so the request
thread waits for it at each of the many points where it gives the interpreter up (a socket read, an image decode).
:class:`ProcessFetcher` does the exchange and the decode in a worker process of its own, as a browser would in a
web worker: the decoded arrays come back through a shared memory block, and the client's thread only waits on a
pipe and copies the arrays out. :class:`ThreadFetcher` does the same work in the calling thread (what a
client without a frame loop, such as a prebake, needs). Both give a :class:`Fetched`.
"""

from __future__ import annotations

import mmap
import multiprocessing
import os
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Literal, Protocol

import httpx
import numpy as np

from baseline_cloudbaking.codecs import CodecError, get_codec
from baseline_cloudbaking.protocol import MEDIA_TYPE, GIMapPayload, PayloadError, decode_payload


class RemoteConfig(Protocol):
    """What a fetcher reads of its client's config (:class:`baseline_cloudbaking.client.RemoteConfig`)."""

    server: str
    codec: str
    resolution: int
    deadline_s: float
    retry_after_s: float
    fetch: str

    def timeout(self) -> httpx.Timeout: ...


#: Where a client's requests run: ``process`` (a worker process per request slot) or ``thread`` (in the client).
FETCHERS = ("process", "thread")
FetcherName = Literal[FETCHERS]  # type: ignore[valid-type]
#: Server stages in the order a payload header reports them (``read`` for a hit; render, denoise,
#: encode for a miss).
SERVER_STAGES = ("lookup", "read", "render", "denoise", "encode")
#: Longest a worker process may take to start and open its shared memory, s.
START_TIMEOUT_S = 60.0


class RequestFailed(Exception):
    """A request that produced no map: ``status`` says how (``overloaded``, ``http_error``, ``timeout``,
    ``connection``, ``bad_payload``); ``retry_after_s``: how long the server asked the client to wait (None: not
    asked)."""

    def __init__(self, status: str, message: str, retry_after_s: float | None = None):
        super().__init__(message)
        self.status = status
        self.retry_after_s = retry_after_s


@dataclass
class Fetched:
    """A finished request: its record's fields known when its response was read and decoded (``status``,
    ``error``, bytes, the server's and the network's stages), its map (None when it failed), when the
    response's last byte arrived (``t_last``, ``time.perf_counter``) and the wait the server asked for."""

    fields: dict[str, Any]
    payload: GIMapPayload | None
    t_last: float
    retry_after_s: float | None = None


def retry_after_s(value: str | None, default: float, longest: float) -> float:
    """Seconds a ``Retry-After`` header asks to wait (delay-seconds or an HTTP date), within [0, ``longest``];
    ``default`` when absent or unreadable."""
    import email.utils

    if value is None:
        return default
    try:
        seconds = float(int(value.strip()))
    except ValueError:
        try:
            seconds = email.utils.parsedate_to_datetime(value).timestamp() - time.time()
        except (TypeError, ValueError, OverflowError):
            return default
    return min(max(seconds, 0.0), longest)


def _header_bytes(headers: httpx.Headers) -> int:
    """Bytes of an HTTP/1.1 header block: ``name: value\\r\\n`` per field and the closing blank line."""
    return sum(len(k) + len(v) + 4 for k, v in headers.raw) + 2


def _http_error(response: httpx.Response) -> str:
    try:
        detail = response.json().get("detail")
    except ValueError:
        detail = response.text[:200]
    return f"HTTP {response.status_code}: {detail}"


def _exchange(client: httpx.Client, cfg: RemoteConfig, body: bytes, t_request: float) -> tuple[dict, bytes, float]:
    """``POST /v1/gimap`` with ``body``: the record's byte counts and first-byte time, the response body, and
    when its last byte arrived; :class:`RequestFailed` for anything but a 200 within the deadline."""
    headers = {"content-type": "application/json", "accept": MEDIA_TYPE}
    try:
        with client.stream("POST", "/v1/gimap", content=body, headers=headers) as response:
            t_first = time.perf_counter()
            request_line = f"POST {response.request.url.raw_path.decode()} HTTP/1.1\r\n"
            fields: dict[str, Any] = {
                "bytes_up": len(request_line) + _header_bytes(response.request.headers) + len(body),
                "t_first": t_first,
            }
            if response.status_code == 503:  # overloaded: wait as long as the server asks
                response.read()
                wait = retry_after_s(response.headers.get("retry-after"), cfg.retry_after_s, cfg.deadline_s)
                raise RequestFailed("overloaded", _http_error(response), wait)
            if response.status_code != 200:
                response.read()
                raise RequestFailed("http_error", _http_error(response))
            chunks = []
            for chunk in response.iter_bytes():
                chunks.append(chunk)
                if time.perf_counter() - t_request > cfg.deadline_s:
                    raise RequestFailed("timeout", f"the response took longer than the {cfg.deadline_s:g} s deadline")
            t_last = time.perf_counter()
            data = b"".join(chunks)
            status_line = f"HTTP/1.1 {response.status_code} OK\r\n"
            fields["bytes_down"] = len(data) + _header_bytes(response.headers) + len(status_line)
    except httpx.TimeoutException as exc:
        raise RequestFailed("timeout", f"{type(exc).__name__} ({exc or 'no detail'})") from None
    except httpx.TransportError as exc:
        raise RequestFailed("connection", f"{type(exc).__name__} ({exc or 'no detail'})") from None
    return fields, data, t_last


def fetch(client: httpx.Client, cfg: RemoteConfig, body: bytes, t_request: float) -> Fetched:
    """One request of ``body`` (asked at ``t_request``) over ``client``, and its payload decoded. The fields:
    ``status`` and ``error``; for a served map the bytes, the server's stages as its header reports them,
    ``request`` (the time to the response's first byte less the server's) and ``transfer`` (first to last byte)."""
    try:
        fields, data, t_last = _exchange(client, cfg, body, t_request)
        try:
            payload = decode_payload(data, cfg.display)
        except (PayloadError, CodecError) as exc:
            raise RequestFailed("bad_payload", str(exc)) from None
    except RequestFailed as exc:
        return Fetched({"status": exc.status, "error": str(exc)}, None, time.perf_counter(), exc.retry_after_s)
    t_first = fields.pop("t_first")
    server = {s: float(payload.timings_ms[s]) for s in SERVER_STAGES if s in payload.timings_ms}
    server_ms = float(payload.timings_ms.get("total", sum(server.values())))
    fields |= {f"{s}_ms": ms for s, ms in server.items()}
    fields |= {
        "status": "ok",
        "request_ms": (t_first - t_request) * 1e3 - server_ms,
        "server_other_ms": server_ms - sum(server.values()),
        "transfer_ms": (t_last - t_first) * 1e3,
        "hit": int(bool(payload.hit)),
        "server_ms": server_ms,
    }
    return Fetched(fields, payload, t_last)


class Fetcher(Protocol):
    """Runs one request at a time (:meth:`fetch`, blocking); ``name`` is one of :data:`FETCHERS`. ``ready`` waits
    until it can fetch; ``warm_up`` runs the codec once and opens the connection (the error of a failed
    ``GET /v1/health``, None when it answered)."""

    name: str

    def ready(self) -> None: ...

    def fetch(self, body: bytes, t_request: float) -> Fetched: ...

    def warm_up(self) -> str | None: ...

    def close(self) -> None: ...


class ThreadFetcher:
    """Requests in the calling thread, over a keep-alive connection of its own."""

    name = "thread"

    def __init__(self, cfg: RemoteConfig):
        self.cfg = cfg
        self.client = httpx.Client(base_url=cfg.server, timeout=cfg.timeout())

    def ready(self) -> None:
        """A thread fetcher is ready once made."""

    def fetch(self, body: bytes, t_request: float) -> Fetched:
        return fetch(self.client, self.cfg, body, t_request)

    def warm_up(self) -> str | None:
        return _warm_up(self.client, self.cfg)

    def close(self) -> None:
        self.client.close()


def _warm_up(client: httpx.Client, cfg: RemoteConfig) -> str | None:
    """Decode a map once (one-off costs stay out of the first request) and open the connection; the error of a
    failed ``GET /v1/health`` (None: it answered)."""
    codec = get_codec(cfg.codec)
    codec.decode(codec.encode(np.zeros((8, 8, 3), np.float32)))
    try:
        client.get("/v1/health").raise_for_status()
    except httpx.HTTPError as exc:
        return str(exc) or type(exc).__name__
    return None


#: The arrays a worker hands back, in the order they lie in its shared block: (name, channels, type).
_LAYOUT = (("gi", 3, np.float32), ("di", 3, np.float32), ("depth", 1, np.float32), ("display", 3, np.uint8))


def _block_bytes(resolution: int) -> int:
    """Bytes of a shared block with room for every array of :data:`_LAYOUT` at ``resolution``."""
    return sum(resolution * resolution * c * np.dtype(t).itemsize for _, c, t in _LAYOUT)


def _views(buffer: mmap.mmap, resolution: int) -> dict[str, np.ndarray]:
    """Views of each array of :data:`_LAYOUT` in ``buffer`` (flat, room for a map of ``resolution``)."""
    out, offset = {}, 0
    for name, channels, dtype in _LAYOUT:
        n = resolution * resolution * channels
        out[name] = np.frombuffer(buffer, dtype, n, offset)
        offset += n * np.dtype(dtype).itemsize
    return out


def _shared_file(size: int) -> tuple[Path, mmap.mmap]:
    """A file of ``size`` bytes in memory (``/dev/shm`` where there is one), mapped; the caller unlinks it once
    the worker has mapped it too, so that nothing is left behind however the processes end."""
    where = "/dev/shm" if os.access("/dev/shm", os.W_OK) else None
    fd, name = tempfile.mkstemp(prefix="gimap-fetch-", dir=where)
    try:
        os.ftruncate(fd, size)
        return Path(name), mmap.mmap(fd, size)
    finally:
        os.close(fd)


def _serve(conn: Connection, cfg: RemoteConfig, path: str, resolution: int) -> None:
    """A worker process: map the shared file, then answer jobs (``("fetch", body, t_request)``, ``("warm_up",)``)
    until the pipe closes. A fetched map's arrays go into the shared block; the reply carries the rest."""
    with open(path, "r+b") as fh:
        buffer = mmap.mmap(fh.fileno(), 0)
    views = _views(buffer, resolution)
    client = httpx.Client(base_url=cfg.server, timeout=cfg.timeout())
    conn.send("ready")
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job[0] == "warm_up":
            conn.send(_warm_up(client, cfg))
            continue
        fetched = fetch(client, cfg, *job[1:])
        reply: dict[str, Any] = {"fields": fetched.fields, "t_last": fetched.t_last, "wait": fetched.retry_after_s}
        p = fetched.payload
        if p is not None:
            arrays = {"gi": p.gi, "di": p.di, "depth": p.depth, "display": p.display}
            reply |= {"header": p.header, "shapes": {k: None if a is None else a.shape for k, a in arrays.items()}}
            fits = all(a is None or a.size <= views[k].size for k, a in arrays.items())
            if not fits:  # a map larger than the block was made for: the run asked for another resolution
                error = f"a {p.depth.shape} map exceeds {resolution}²"
                reply = {"fields": {"status": "bad_payload", "error": error}}
                reply |= {"t_last": fetched.t_last, "wait": None}
            else:
                for k, a in arrays.items():
                    if a is not None:
                        views[k][: a.size] = a.ravel()
        reply["t_decoded"] = time.perf_counter()
        conn.send(reply)


class ProcessFetcher:
    """Requests in a worker process (see the module docstring) whose maps are at most ``resolution``²."""

    name = "process"

    def __init__(self, cfg: RemoteConfig):
        self.cfg = cfg
        self._path, self._buffer = _shared_file(_block_bytes(cfg.resolution))
        self._views = _views(self._buffer, cfg.resolution)
        ctx = multiprocessing.get_context("spawn")  # the client's process holds a GL context and threads: no fork
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(
            target=_serve, args=(child, cfg, str(self._path), cfg.resolution), name="gimap-fetch", daemon=True
        )
        try:
            self._process.start()
        except BaseException:
            self.close()
            raise
        finally:
            child.close()

    def ready(self) -> None:
        """Wait until the worker has started and mapped the shared block (then its file is removed)."""
        try:
            if not self._conn.poll(START_TIMEOUT_S) or self._conn.recv() != "ready":
                raise RuntimeError(f"the GI-map fetch worker did not start within {START_TIMEOUT_S:g} s")
        except (EOFError, OSError):
            raise RuntimeError("the GI-map fetch worker ended as it started (see its error above)") from None
        finally:
            self._path.unlink(missing_ok=True)

    def fetch(self, body: bytes, t_request: float) -> Fetched:
        try:
            self._conn.send(("fetch", body, t_request))
            reply = self._conn.recv()
        except (EOFError, OSError):
            error = "the fetch worker process ended (closed, or killed)"
            return Fetched({"status": "connection", "error": error}, None, time.perf_counter())
        payload = None
        if reply["fields"]["status"] == "ok":
            arrays = {k: self._copy(k, shape) for k, shape in reply["shapes"].items()}
            payload = GIMapPayload.of(reply["header"], arrays["gi"], arrays["di"], arrays["depth"], arrays["display"])
            reply["fields"]["handoff_ms"] = (time.perf_counter() - reply["t_decoded"]) * 1e3
        return Fetched(reply["fields"], payload, reply["t_last"], reply["wait"])

    def _copy(self, name: str, shape: tuple[int, ...] | None) -> np.ndarray | None:
        """The array ``name`` of the last reply, copied out of the shared block (the worker reuses it)."""
        return None if shape is None else self._views[name][: int(np.prod(shape))].reshape(shape).copy()

    def warm_up(self) -> str | None:
        self._conn.send(("warm_up",))
        return self._conn.recv()

    def close(self) -> None:
        """End the worker (a request in flight ends with it) and the pipe. The shared block is unmapped with this
        object: the maps were copied out of it."""
        if self._process.pid is not None:
            self._process.kill()
            self._process.join(timeout=5.0)
        self._conn.close()
        self._path.unlink(missing_ok=True)


def open_fetcher(cfg: RemoteConfig) -> Fetcher:
    """The fetcher ``cfg.fetch`` names, for maps of ``cfg.resolution``."""
    return ProcessFetcher(cfg) if cfg.fetch == "process" else ThreadFetcher(cfg)
