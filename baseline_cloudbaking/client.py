"""The cloud-baking client's GI source: GI maps asked from a ``cloudbaking-server`` over HTTP (SPEC §6).

:class:`RemoteSource` is a :class:`gicore.loop.GISource` that works in one background thread with one
keep-alive ``httpx`` connection and at most one request in flight: :meth:`~RemoteSource.request`
hands the GI camera to the thread and returns at once (False while a request is in flight or, after a
failure, for ``retry_after_s``), :meth:`~RemoteSource.latest` returns the newest map that has arrived.
A failed request (connect or read timeout, total deadline, dropped connection, an HTTP error, a bad
payload) is logged and recorded; the loop goes on composing with the map it has.

How each request's time is split (``stages`` of its :class:`~gicore.loop.GIMap`, which sum to its
latency, request to arrival):

- ``request``: from :meth:`~RemoteSource.request` to the first byte of the response (its status line
  and headers), minus the server's own time. It holds the hand-off to the thread, the request's
  upload, the link's round trip, and the HTTP and proxy overhead at both ends. The client cannot split
  the round trip into its two one-way delays without synchronised clocks, so the response's
  propagation delay is counted here, paid by its first bytes;
- the server's time, from the payload header's ``timings_ms`` (measured inside the server, from the
  parsed request to the finished payload): ``lookup``, then ``read`` (a hit) or ``render``,
  ``denoise``, ``encode`` (a miss), and ``server_other`` = the server's total minus those (storing a
  miss in the GI tree, re-packing the header);
- ``transfer``: first to last byte of the response, i.e. the body's serialization at the link's rate
  (its propagation delay is already in ``request``);
- ``decode``: the GI map (and DI) codec and the depth section.

``transmission`` = ``request`` + ``transfer`` is the network's share. Each request's record (see
:data:`RECORD_COLUMNS`) also has the bytes each way (body plus HTTP header bytes; TCP/IP headers are not
counted), the hit flag, and ``pickup_ms``: arrival to the first :meth:`~RemoteSource.latest` call that
returned the map, i.e. how long it waited for the loop's next frame.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Literal

import httpx
import numpy as np

from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC, CodecError, get_codec
from baseline_cloudbaking.protocol import MEDIA_TYPE, PayloadError, decode_payload
from gicore.camera import Camera
from gicore.loop import GIMap, Light, PathRunConfig

log = logging.getLogger("cloudbaking.client")

#: Server stages in the order a payload header reports them (``read`` for a hit; render, denoise,
#: encode for a miss).
SERVER_STAGES = ("lookup", "read", "render", "denoise", "encode")
#: Every stage a map reports, in the order they happen.
STAGES = ("request", *SERVER_STAGES, "server_other", "transfer", "decode")
#: Columns of a request's record (``<stage>_ms`` for every stage of :data:`STAGES`).
RECORD_COLUMNS = (
    "request_id", "frame", "status", "error", "hit", "requested_s", "bytes_up", "bytes_down",
    *(f"{s}_ms" for s in STAGES), "server_ms", "transmission_ms", "latency_ms", "pickup_ms",
)  # fmt: skip


@dataclass(frozen=True)
class RemoteConfig:
    """Where the GI maps come from and what they are. ``cloudbaking-client`` makes it from its
    :class:`CloudClientConfig` (:meth:`CloudClientConfig.remote`), so the maps asked for are the run's; its
    defaults are that config's."""

    #: Base URL of the server (or of a network proxy in front of it), e.g. ``http://127.0.0.1:8000``.
    server: str
    #: The scene's name on the server (a spec file's stem).
    scene: str
    #: Square map resolution (one the server serves).
    resolution: int = PathRunConfig.resolution
    #: GI-map codec.
    codec: str = DEFAULT_CODEC
    #: Path-tracing samples per pixel of the server's maps.
    spp: int = PathRunConfig.spp
    #: Also ask for the DI of the GI view (the residual composition subtracts it to get the indirect light).
    di: bool = False
    #: Whether the scene's light moves: a static light's position is not sent (the server refuses it).
    light_moves: bool = True
    #: Longest wait for the TCP connection, s.
    connect_timeout_s: float = 5.0
    #: Longest silence while waiting for or reading the response, s (so it bounds the server's render time).
    read_timeout_s: float = 30.0
    #: Longest a whole request may take, s (a response trickling in too slowly for it is abandoned).
    deadline_s: float = 60.0
    #: After a failed request, no new one is sent for this long, s (a dead server is not asked every frame).
    retry_after_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("connect_timeout_s", "read_timeout_s", "deadline_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.retry_after_s >= 0:
            raise ValueError(f"retry_after_s must be >= 0, got {self.retry_after_s}")

    def timeout(self) -> httpx.Timeout:
        return httpx.Timeout(
            connect=self.connect_timeout_s,
            read=self.read_timeout_s,
            write=self.read_timeout_s,
            pool=self.connect_timeout_s,
        )

    def body(self, camera: Camera, light: Light) -> bytes:
        """The JSON body of a ``POST /v1/gimap`` for the GI ``camera`` under ``light``."""
        request: dict[str, Any] = {
            "scene": self.scene,
            "camera": {
                "eye": list(camera.origin),
                "target": list(camera.target),
                "up": list(camera.up),
                "fov": camera.fov,
            },
            "resolution": self.resolution,
            "codec": self.codec,
            "spp": self.spp,
            "di": self.di,
        }
        if self.light_moves:
            request["light"] = [float(v) for v in light]
        return json.dumps(request).encode()


class RequestFailed(Exception):
    """A request that produced no map: ``status`` says how (see :meth:`RemoteSource._fetch`)."""

    def __init__(self, status: str, message: str):
        super().__init__(message)
        self.status = status


def _header_bytes(headers: httpx.Headers) -> int:
    """Bytes of an HTTP/1.1 header block: ``name: value\\r\\n`` per field and the closing blank line."""
    return sum(len(k) + len(v) + 4 for k, v in headers.raw) + 2


def _http_error(response: httpx.Response) -> str:
    try:
        detail = response.json().get("detail")
    except ValueError:
        detail = response.text[:200]
    return f"HTTP {response.status_code}: {detail}"


class RemoteSource:
    """GI maps from a cloud-baking server, fetched in a background thread (see the module docstring).

    ``records``: one dict per finished request (:data:`RECORD_COLUMNS`), in the order they finished.
    Use as a context manager, or call :meth:`close`.
    """

    name = "cloud"
    stages = STAGES

    def __init__(self, cfg: RemoteConfig):
        self.cfg = cfg
        self.client = httpx.Client(base_url=cfg.server, timeout=cfg.timeout())
        self.records: list[dict[str, Any]] = []
        self._t0 = time.perf_counter()
        self._cond = threading.Condition()
        self._job: tuple[Camera, Light, int, float] | None = None  # (GI camera, light, frame, request time)
        self._in_flight: tuple[Camera, Light, int, float] | None = None
        self._busy = False
        self._closed = False
        self._not_before = 0.0
        self._latest: GIMap | None = None
        self._unpicked: dict[str, Any] | None = None  # the record of the newest map, until the loop takes it
        self._thread = threading.Thread(target=self._work, name="gimap-requests", daemon=True)
        self._thread.start()

    # -- GISource --------------------------------------------------------------------------------------
    def request(self, camera: Camera, light: Light, frame: int) -> bool:
        with self._cond:
            if self._busy or self._closed or time.perf_counter() < self._not_before:
                return False
            self._busy = True
            self._job = (camera, light, frame, time.perf_counter())
            self._cond.notify()
        return True

    def latest(self) -> GIMap | None:
        with self._cond:
            gi = self._latest
            if gi is not None and self._unpicked is not None:
                self._unpicked["pickup_ms"] = (time.perf_counter() - gi.arrived_at) * 1e3
                self._unpicked = None
            return gi

    def warm_up(self, camera: Camera, light: Light) -> None:
        """Open the keep-alive connection (``GET /v1/health``) and run the codec once, both untimed."""
        codec = get_codec(self.cfg.codec)
        codec.decode(codec.encode(np.zeros((8, 8, 3), np.float32)))
        try:
            self.client.get("/v1/health").raise_for_status()
        except httpx.HTTPError as exc:
            log.warning("warm-up: GET /v1/health failed (%s); the first request will open the connection", exc)

    # -- lifecycle -------------------------------------------------------------------------------------
    def wait(self, timeout: float) -> bool:
        """Block until no request is in flight (True) or ``timeout`` s have passed (False)."""
        deadline = time.perf_counter() + timeout
        with self._cond:
            while self._busy:
                left = deadline - time.perf_counter()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def close(self) -> None:
        """Stop the thread (a request in flight is abandoned) and close the connection."""
        with self._cond:
            self._closed = True
            if self._in_flight is not None:
                frame, t_request = self._in_flight[2:]
                record = dict.fromkeys(RECORD_COLUMNS, "") | {
                    "request_id": len(self.records),
                    "frame": frame,
                    "status": "abandoned",
                }
                record |= {"error": "still in flight when the run ended", "requested_s": t_request - self._t0}
                record["latency_ms"] = (time.perf_counter() - t_request) * 1e3
                self.records.append(record)
            self._cond.notify_all()
        self._thread.join(timeout=1.0)
        self.client.close()

    def __enter__(self) -> RemoteSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the thread ------------------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            with self._cond:
                while self._job is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                job, self._job = self._job, None
                self._in_flight = job
            try:
                record, gi = self._fetch(*job)
            except Exception:
                if self._closed:  # the connection was closed under a request that close() abandoned
                    return
                raise
            with self._cond:
                if self._closed:  # close() recorded it as abandoned
                    return
                self._in_flight = None
                self.records.append(record)
                if gi is not None:
                    self._latest, self._unpicked = gi, record
                else:
                    self._not_before = time.perf_counter() + self.cfg.retry_after_s
                self._busy = False
                self._cond.notify_all()

    def _fetch(self, camera: Camera, light: Light, frame: int, t_request: float) -> tuple[dict[str, Any], GIMap | None]:
        """One request: its record, and its map (None if it failed)."""
        cfg = self.cfg
        body = cfg.body(camera, light)
        record: dict[str, Any] = dict.fromkeys(RECORD_COLUMNS, "")
        record |= {"request_id": len(self.records), "frame": frame, "status": "ok", "requested_s": t_request - self._t0}
        headers = {"content-type": "application/json", "accept": MEDIA_TYPE}
        try:
            try:
                with self.client.stream("POST", "/v1/gimap", content=body, headers=headers) as response:
                    t_first = time.perf_counter()
                    request_line = f"POST {response.request.url.raw_path.decode()} HTTP/1.1\r\n"
                    record["bytes_up"] = len(request_line) + _header_bytes(response.request.headers) + len(body)
                    if response.status_code != 200:
                        response.read()
                        raise RequestFailed("http_error", _http_error(response))
                    chunks = []
                    for chunk in response.iter_bytes():
                        chunks.append(chunk)
                        if time.perf_counter() - t_request > cfg.deadline_s:
                            raise RequestFailed(
                                "timeout", f"the response took longer than the {cfg.deadline_s:g} s deadline"
                            )
                    t_last = time.perf_counter()
                    data = b"".join(chunks)
                    record["bytes_down"] = (
                        len(data) + _header_bytes(response.headers) + len(f"HTTP/1.1 {response.status_code} OK\r\n")
                    )
            except httpx.TimeoutException as exc:
                raise RequestFailed("timeout", f"{type(exc).__name__} ({exc or 'no detail'})") from None
            except httpx.TransportError as exc:
                raise RequestFailed("connection", f"{type(exc).__name__} ({exc or 'no detail'})") from None
            try:
                payload = decode_payload(data)
            except (PayloadError, CodecError) as exc:
                raise RequestFailed("bad_payload", str(exc)) from None
        except RequestFailed as exc:
            record |= {"status": exc.status, "error": str(exc), "latency_ms": (time.perf_counter() - t_request) * 1e3}
            log.warning("GI-map request %d (frame %d) failed: %s: %s", record["request_id"], frame, exc.status, exc)
            return record, None
        arrived = time.perf_counter()
        server = {s: float(payload.timings_ms[s]) for s in SERVER_STAGES if s in payload.timings_ms}
        server_ms = float(payload.timings_ms.get("total", sum(server.values())))
        stages = {
            "request": (t_first - t_request) * 1e3 - server_ms,
            **server,
            "server_other": server_ms - sum(server.values()),
        }
        stages |= {"transfer": (t_last - t_first) * 1e3, "decode": (arrived - t_last) * 1e3}
        record |= {f"{s}_ms": ms for s, ms in stages.items()}
        record |= {
            "hit": int(bool(payload.hit)),
            "server_ms": server_ms,
            "transmission_ms": stages["request"] + stages["transfer"],
            "latency_ms": (arrived - t_request) * 1e3,
        }
        gi = GIMap(
            payload.camera,
            payload.gi,
            payload.depth,
            payload.di,
            frame=frame,
            requested_at=t_request,
            arrived_at=arrived,
            stages=stages,
        )
        return record, gi


# -- the client process's run ------------------------------------------------------------------------------
#: Columns of ``requests.csv``: a request's record, then what the frame that bound its map spent on it.
REQUEST_COLUMNS = (*RECORD_COLUMNS, "bound_frame", "di_ms", "bind_ms", "warp_ms", "blend_ms", "total_ms")


@dataclass(frozen=True)
class ServerInfo:
    """What the client learns from the server at start-up (``GET /v1/scenes``)."""

    #: Δp / Δθ of the server's GI tree: the client asks again once its view leaves them.
    tolerance_position: float
    tolerance_angle_deg: float


def check_server(server: str, scene: str, resolution: int, codec: str, spp: int, timeout_s: float) -> ServerInfo:
    """Ask the server for its health and scenes; a :class:`~gicore.cli.UserError` naming the option at
    fault if it is unreachable, is not a cloud-baking server, or does not serve what the client needs."""
    from gicore.cli import UserError

    try:
        url = httpx.URL(server)
    except httpx.InvalidURL as exc:
        raise UserError(
            f"--server {server!r} is not a URL ({exc})", "give the server's base URL, e.g. http://127.0.0.1:8000"
        ) from None
    if url.scheme not in ("http", "https") or not url.host:
        raise UserError(
            f"--server {server!r} is not an http(s) URL", "give the server's base URL, e.g. http://127.0.0.1:8000"
        )
    try:
        with httpx.Client(base_url=url, timeout=timeout_s) as client:
            health = client.get("/v1/health")
            scenes = client.get("/v1/scenes") if health.status_code == 200 else health
    except httpx.TimeoutException:
        raise UserError(
            f"--server {server}: no answer to GET /v1/health within {timeout_s:g} s",
            "check the server and the network to it",
        ) from None
    except httpx.TransportError as exc:
        raise UserError(
            f"--server {server}: cannot connect ({exc})", "start cloudbaking-server there, or fix the URL"
        ) from None
    try:
        if health.status_code != 200 or health.json().get("status") != "ok" or scenes.status_code != 200:
            raise ValueError
        info = scenes.json()
        served = {s["name"] for s in info["scenes"]}
        resolutions, codecs, max_spp = info["resolutions"], info["codecs"], int(info["max_spp"])
        tolerance = ServerInfo(float(info["tolerance_position"]), float(info["tolerance_angle_deg"]))
    except (ValueError, KeyError, TypeError):
        what = f"--server {server} does not answer like a cloudbaking-server (GET /v1/health: {health.status_code})"
        raise UserError(what, "check the URL") from None
    if scene not in served:
        todo = f"use one of {', '.join(sorted(served))}, or start the server with its spec in --scenes"
        raise UserError(f"--scene {scene!r} is not served by {server}", todo)
    if resolution not in resolutions:
        raise UserError(
            f"--resolution {resolution} is not served by {server}", f"use one of {', '.join(map(str, resolutions))}"
        )
    if codec not in codecs:
        raise UserError(f"--codec {codec!r} is not served by {server}", f"use one of {', '.join(codecs)}")
    if spp > max_spp:
        raise UserError(f"--spp {spp} exceeds the server's max_spp {max_spp}", f"use --spp {max_spp} or less")
    return tolerance


#: Field metadata of a client timeout, s.
TIMEOUT_S = {"min": 0.001, "max": 3600.0}


@dataclass(frozen=True)
class CloudClientConfig(PathRunConfig):
    """One ``cloudbaking-client`` run: the shared path run (the same path as ``gigan-client``'s; ``spp`` is
    also the server's; the server's maps are always denoised) plus the GI-map codec and the timeouts of its
    requests. The server knows the scene by its name (a spec file's stem). Its command line is derived from
    these fields and :class:`~gicore.loop.PathRunConfig`'s."""

    #: GI-map codec.
    codec: Literal[CODEC_NAMES] = DEFAULT_CODEC  # type: ignore[valid-type]
    #: Seconds to wait for a TCP connection.
    connect_timeout: float = field(default=RemoteConfig.connect_timeout_s, metadata=TIMEOUT_S)
    #: Seconds of silence that fail a request (bounds the server's render time).
    read_timeout: float = field(default=RemoteConfig.read_timeout_s, metadata=TIMEOUT_S)
    #: Seconds after which a request fails however it is going.
    deadline: float = field(default=RemoteConfig.deadline_s, metadata=TIMEOUT_S)

    @property
    def server_name(self) -> str:
        return Path(self.scene).stem

    def remote(self, server: str, light_moves: bool) -> RemoteConfig:
        """What to ask ``server`` for: this run's maps (its resolution, codec and spp, the DI where the
        composition needs it) within its timeouts; ``light_moves``: whether the scene's light moves."""
        return RemoteConfig(
            server, self.server_name, self.resolution, self.codec, self.spp, di=self.composition == "residual",
            light_moves=light_moves, connect_timeout_s=self.connect_timeout, read_timeout_s=self.read_timeout,
            deadline_s=self.deadline,
        )  # fmt: skip


def run_client(
    cfg: CloudClientConfig, server: str, tolerance: ServerInfo
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], str]:
    """Fly the scene's camera path composing with ``server``'s maps; returns (per-frame rows, per-request rows,
    the renderer that ran the per-frame raster passes: ``"mitsuba"`` when ``gl`` was asked and no GL context
    opened, see :func:`gicore.loop.open_raster`).

    The local DI and the warp's surface-mask pass use ``cfg.renderer``; the GT stays with Mitsuba. Composed
    frames of scored frames are kept and scored against the GT after the run, so the GT renders neither
    delay frames nor change when requests go out.
    """
    from baseline_cloudbaking.warp import PixelWarp
    from gicore.gl import GLRenderer, RasterUnavailable
    from gicore.loop import CLIENT_LOD, LAYERS, ClientLoop, GroundTruth, LoopConfig, open_raster, path_views, run_frames
    from gicore.render import Renderer
    from gicore.scene import load_scene

    spec = load_scene(cfg.scene)
    remote = cfg.remote(server, spec.light.moves)
    renderer = Renderer(spec, cfg.resolution)
    gl = partial(GLRenderer, spec, cfg.resolution, lod=CLIENT_LOD)
    raster, used = open_raster(cfg.renderer, renderer, gl, RasterUnavailable)
    loop_cfg = LoopConfig(
        every=cfg.every, gi_fov=cfg.gi_fov_of(spec), max_move=tolerance.tolerance_position or None,
        max_turn=tolerance.tolerance_angle_deg or None, composition=cfg.composition, tau=cfg.tau, seed=cfg.seed,
        first_map_timeout_s=remote.connect_timeout_s + remote.deadline_s,
    )  # fmt: skip
    views = path_views(spec, cfg.frames, cfg.orbit_frames, cfg.seed, cfg.local_fov_of(spec), cfg.resolution)
    kept: dict[int, np.ndarray] = {}

    def keep(frame: int, result) -> None:
        if cfg.gt_every and frame % cfg.gt_every == 0:
            kept[frame] = result.image

    with RemoteSource(remote) as source:
        warp = PixelWarp(raster, LAYERS[cfg.composition])
        rows = run_frames(ClientLoop(loop_cfg, raster, source, warp), views, None, keep)
    if kept:
        ground_truth = GroundTruth(renderer, cfg.gt_every, cfg.spp, cfg.denoise, cfg.seed)
        for frame, image in kept.items():
            rows[frame] |= ground_truth.score(frame, *views[frame], image)
    return rows, join_requests(source.records, rows, tuple(s for s in warp.stages if s != "bind")), used


def join_requests(
    records: list[dict[str, Any]], rows: list[dict[str, Any]], warp_stages: tuple[str, ...]
) -> list[dict[str, Any]]:
    """Per-request rows: each record with what the frame that bound its map spent on its local DI render, bind,
    warp and blend, and ``total_ms``: every stage from the request to that frame's composition, summed (the
    frame's DI included: the map is not seen before it; the wait for the next frame, ``pickup_ms``, is not a
    stage and is not in it)."""
    bound = {int(r["frame"]) - int(r["gi_age_frames"]): r for r in rows if r["gi_new"]}
    out = []
    for record in records:
        row = dict.fromkeys(REQUEST_COLUMNS, "") | record
        frame = bound.get(record["frame"])
        if record["status"] == "ok" and frame is not None:
            warp_ms = sum(float(frame[f"{s}_ms"]) for s in warp_stages)
            stages = sum(float(record[f"{s}_ms"]) for s in STAGES if record[f"{s}_ms"] != "")
            row |= {
                "bound_frame": frame["frame"],
                "di_ms": frame["di_ms"],
                "bind_ms": frame["bind_ms"],
                "warp_ms": warp_ms,
                "blend_ms": frame["compose_ms"],
            }
            local = float(frame["di_ms"]) + float(frame["bind_ms"]) + warp_ms + float(frame["compose_ms"])
            row["total_ms"] = stages + local
        out.append(row)
    return out


def request_summary(requests: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts by status and cache state, and median latency and total of the served requests."""
    ok = [r for r in requests if r["status"] == "ok"]
    statuses = [r["status"] for r in requests]
    summary: dict[str, Any] = {
        "requests": len(requests),
        "status": {s: statuses.count(s) for s in dict.fromkeys(statuses)},
    }
    summary |= {"hits": sum(int(r["hit"]) for r in ok), "misses": sum(1 - int(r["hit"]) for r in ok)}
    for column in ("latency_ms", "transmission_ms", "total_ms"):
        values = [float(r[column]) for r in ok if r[column] != ""]
        summary[f"median_{column}"] = float(np.median(values)) if values else None
    return summary
