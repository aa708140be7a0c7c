"""The cloud-baking client's GI source: GI maps asked from a ``cloudbaking-server`` over HTTP
(docs/architecture.md, Data flow of a cloud-baking frame).

:class:`RemoteSource` is a :class:`gicore.loop.GISource` that works in background threads over keep-alive
``httpx`` connections: :meth:`~RemoteSource.request` hands the GI camera to a thread and returns at once,
:meth:`~RemoteSource.latest` returns the newest map that has arrived (with a tolerance, the held one that
serves the view best). A failed request is logged and recorded; the loop keeps composing with the map it has.
A request's time is split into ``request``, the server's own stages, ``transfer`` and ``decode``, which sum to
its latency (:data:`RECORD_COLUMNS`). :class:`RequestPolicy` decides when to ask (only when no held or
in-flight map serves the view by the GI tree's rule) and :class:`MotionPredictor` what to ask for when it
prefetches (docs/architecture.md, Request policy and prefetch).
"""

from __future__ import annotations

import email.utils
import json
import logging
import math
import threading
import time
import weakref
from collections import deque
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import httpx
import numpy as np

from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC, CodecError, get_codec
from baseline_cloudbaking.protocol import MEDIA_TYPE, PayloadError, decode_payload
from baseline_cloudbaking.viewpoints import Tolerance, Viewpoint, light_cell, nearest
from gicore.camera import Camera
from gicore.loop import GIMap, Light, PathRunConfig

if TYPE_CHECKING:
    from gicore.path_file import PathFile

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


# -- when to ask: the server's tolerance, and prefetch --------------------------------------------------------
#: Prefetch policies (:attr:`CloudClientConfig.prefetch`).
PREFETCH = ("none", "extrapolate")
#: Request rules (:attr:`CloudClientConfig.hold`).
HOLDS = ("tolerance", "none")
#: Arrived maps a source keeps to serve later views (a prefetched map arrives before its view is reached).
KEPT_MAPS = 4
LightCell = tuple[int, int, int] | None
#: A request handed to the workers: GI camera, light, frame, request time, request id.
Job = tuple[Camera, Light, int, float, int]


@dataclass(frozen=True)
class RequestPolicy:
    """When a :class:`RemoteSource` sends the requests the loop asks for (module docstring)."""

    #: The server's tolerance; None: send whenever asked and free (the loop's period k and its own test decide).
    tolerance: Tolerance | None = None
    #: The server's light-cell side for the scene (None: a static light, no light level in the tree's keys).
    light_cell: float | None = None
    #: ``none`` or ``extrapolate`` (needs ``tolerance``).
    prefetch: str = "none"
    #: Recent frames whose motion is extrapolated.
    history: int = 8
    #: Recent requests whose median latency sets the prefetch lead.
    latencies: int = 8
    #: Requests in flight at most (each on its own connection); with prefetch, successive views ahead.
    in_flight: int = 1

    def __post_init__(self) -> None:
        if self.prefetch not in PREFETCH:
            raise ValueError(f"prefetch must be one of {PREFETCH}, got {self.prefetch!r}")
        if self.prefetch != "none" and self.tolerance is None:
            raise ValueError("prefetch needs the server's tolerance (a map is asked ahead only when none held serves)")
        if self.history < 2 or self.latencies < 1 or self.in_flight < 1:
            raise ValueError(
                f"history must be >= 2, latencies and in_flight >= 1, got {self.history}, {self.latencies} and"
                f" {self.in_flight}"
            )

    def cell(self, light: Light) -> LightCell:
        return light_cell(light, self.light_cell)


def covers(map_camera: Camera, map_cell: LightCell, camera: Camera, cell: LightCell, tol: Tolerance) -> bool:
    """Whether a map at ``map_camera`` (made in light cell ``map_cell``) serves a request at ``camera`` in light
    cell ``cell``: the GI tree's own lookup rule (:func:`baseline_cloudbaking.viewpoints.nearest`)."""
    if map_cell != cell:
        return False
    held = _viewpoint(map_camera)
    return nearest(np.array([held.eye]), np.array([held.direction]), _viewpoint(camera), tol) is not None


def _viewpoint(camera: Camera) -> Viewpoint:
    return Viewpoint.look_at(camera.origin, camera.target)


class MotionPredictor:
    """The recent motion of the camera and the light (the last ``history`` views: frame, when it was asked for,
    camera, light), extrapolated: eye position, view direction and light position fitted against the frame number
    by least squares (a parabola from five views on, as an orbit bends; a line before), evaluated the frames ahead
    that a lead in seconds spans at the median frame interval. Fitting against frames, not request times, keeps
    the jitter of when in its frame a view was asked for out of the motion; the direction is renormalised. The
    light is predicted too: a map asked ahead under the current light would miss the maps baked past a light-cell
    boundary."""

    def __init__(self, history: int):
        self._views: deque[tuple[int, float, np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=history)

    def add(self, frame: int, t: float, camera: Camera, light: Light) -> None:
        if self._views and frame <= self._views[-1][0]:  # a frame asked twice (or a restart): keep the motion
            return
        view = _viewpoint(camera)
        self._views.append((frame, t, np.array(view.eye), np.array(view.direction), np.array(light, dtype=float)))

    def frame_interval_s(self) -> float | None:
        """Median time per frame between the views (None before two)."""
        if len(self._views) < 2:
            return None
        frames = np.diff([v[0] for v in self._views])
        return float(np.median(np.diff([v[1] for v in self._views]) / frames))

    def crossing_s(self, tol: Tolerance) -> float | None:
        """Time the camera takes to move one tolerance (its eye ``tol.position`` or its direction ``tol.angle_deg``,
        whichever comes first) at its last speed; None before two views or when it stands still."""
        interval = self.frame_interval_s()
        if interval is None:
            return None
        (f0, _, e0, d0, _), (f1, _, e1, d1, _) = self._views[-2], self._views[-1]
        move = float(np.linalg.norm(e1 - e0)) / max(tol.position, 1e-12)
        turn = math.degrees(math.atan2(float(np.linalg.norm(np.cross(d0, d1))), float(d0 @ d1)))
        per_frame = max(move, turn / max(tol.angle_deg, 1e-12)) / (f1 - f0)
        return interval / per_frame if per_frame > 0.0 else None

    def predict(self, camera: Camera, lead_s: float) -> tuple[Camera, Light] | None:
        """``camera`` moved to where its motion puts it ``lead_s`` after the last view (its distance to its
        target, its up and FOV kept), and the light then; None before three views."""
        interval = self.frame_interval_s()
        if len(self._views) < 3 or interval is None or not interval > 0.0:
            return None
        f = np.array([v[0] for v in self._views], dtype=float)
        f -= f[-1]
        ahead = lead_s / interval
        degree = 2 if len(f) >= 5 else 1
        eye, d, light = (
            np.array([np.polyval(np.polyfit(f, values[:, i], degree), ahead) for i in range(3)])
            for values in (np.array([v[k] for v in self._views]) for k in (2, 3, 4))
        )
        norm = float(np.linalg.norm(d))
        if not (np.isfinite(eye).all() and np.isfinite(light).all() and math.isfinite(norm) and norm > 1e-9):
            return None
        reach = float(np.linalg.norm(np.subtract(camera.target, camera.origin)))
        try:
            moved = replace(camera, origin=tuple(eye), target=tuple(eye + d / norm * reach))
        except ValueError:  # e.g. a view direction parallel to up: ask for the view as it is
            return None
        return moved, (float(light[0]), float(light[1]), float(light[2]))


def retry_after_s(value: str | None, default: float, longest: float) -> float:
    """Seconds a ``Retry-After`` header asks to wait (delay-seconds or an HTTP date), within [0, ``longest``];
    ``default`` when absent or unreadable."""
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


class RequestFailed(Exception):
    """A request that produced no map: ``status`` says how (see :meth:`RemoteSource._fetch`);
    ``retry_after_s``: how long the server asked the client to wait (None: not asked)."""

    def __init__(self, status: str, message: str, retry_after_s: float | None = None):
        super().__init__(message)
        self.status = status
        self.retry_after_s = retry_after_s


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
    """GI maps from a cloud-baking server, fetched in a background thread (see the module docstring), sent
    when ``policy`` says so.

    ``records``: one dict per finished request (:data:`RECORD_COLUMNS`), in the order they finished.
    Use as a context manager, or call :meth:`close`.
    """

    name = "cloud"
    stages = STAGES

    def __init__(self, cfg: RemoteConfig, policy: RequestPolicy = RequestPolicy()):
        self.cfg = cfg
        self.policy = policy
        self.motion = MotionPredictor(policy.history)
        self.kept: deque[tuple[GIMap, LightCell]] = deque(maxlen=KEPT_MAPS)  # arrived maps, newest last
        self._view: tuple[Camera, LightCell] | None = None  # the last view asked for
        self.client = httpx.Client(base_url=cfg.server, timeout=cfg.timeout())
        self.records: list[dict[str, Any]] = []
        self._t0 = time.perf_counter()
        self._cond = threading.Condition()
        self._jobs: deque[Job] = deque()  # asked for, not yet taken by a worker
        self._in_flight: list[Job] = []  # being fetched
        self._asked = 0  # requests so far: the next one's id
        self._closed = False
        self._not_before = 0.0
        self._unpicked: dict[GIMap, dict[str, Any]] = {}  # the records of maps the loop has not taken yet
        self._cells: weakref.WeakKeyDictionary[GIMap, LightCell] = weakref.WeakKeyDictionary()
        self._threads = [
            threading.Thread(target=self._work, name=f"gimap-requests-{i}", daemon=True)
            for i in range(policy.in_flight)
        ]
        for thread in self._threads:
            thread.start()

    # -- GISource --------------------------------------------------------------------------------------
    @property
    def started_at(self) -> float:
        """The ``time.perf_counter()`` stamp that records' ``requested_s`` count from."""
        return self._t0

    def request(self, camera: Camera, light: Light, frame: int) -> bool:
        now = time.perf_counter()
        with self._cond:
            if self._closed:
                return False
            if self.policy.tolerance is not None:
                self.motion.add(frame, now, camera, light)
                self._view = (camera, self.policy.cell(light))
            if self._pending() >= self.policy.in_flight or now < self._not_before:
                return False
            target = (camera, light) if self.policy.tolerance is None else self._target(camera, light)
            if target is None:
                return False
            self._jobs.append((*target, frame, now, self._asked))
            self._asked += 1
            self._cond.notify()
        return True

    def latest(self) -> GIMap | None:
        """The held map that best serves the last view asked for (the newest when none does, or without a
        tolerance)."""
        with self._cond:
            if not self.kept:
                return None
            gi = self.kept[-1][0]
            if self._view is not None:
                best = self._serving(*self._view, in_flight=False)
                gi = self.kept[best][0] if best is not None else gi
            record = self._unpicked.pop(gi, None)
            if record is not None:
                record["pickup_ms"] = (time.perf_counter() - gi.arrived_at) * 1e3
            return gi

    def cell_of(self, gi: GIMap) -> LightCell:
        """The light cell of a map this source returned (the cell of the light it was asked under)."""
        with self._cond:
            return self._cells[gi]

    # -- the request rule (call with the lock held) ------------------------------------------------------------
    def _pending(self) -> int:
        return len(self._jobs) + len(self._in_flight)

    def _serving(self, camera: Camera, cell: LightCell, in_flight: bool) -> int | None:
        """Index in :attr:`kept` of the held map that best serves the view (by the tree's score), -1 for a map
        asked for (``in_flight``: when one serves and no held one does), None when none does."""
        tol = self.policy.tolerance
        assert tol is not None
        mine = [i for i, (_, c) in enumerate(self.kept) if c == cell]
        if mine:
            views = [_viewpoint(self.kept[i][0].camera) for i in mine]
            eyes, dirs = np.array([v.eye for v in views]), np.array([v.direction for v in views])
            found = nearest(eyes, dirs, _viewpoint(camera), tol)
            if found is not None:
                return mine[found[0]]
        if in_flight and any(
            covers(target, self.policy.cell(light), camera, cell, tol)
            for target, light, *_ in (*self._jobs, *self._in_flight)
        ):
            return -1
        return None

    def _lead_s(self) -> float | None:
        """How far ahead to ask: the median latency of the last served requests plus half a frame interval (when
        the map is shown), plus half the time the camera takes to cross the tolerance, so that the map serves the
        view from its arrival on for as long as it can (None before a request was served)."""
        served = [float(r["latency_ms"]) for r in self.records if r["status"] == "ok"][-self.policy.latencies :]
        interval = self.motion.frame_interval_s()
        if not served or interval is None:
            return None
        assert self.policy.tolerance is not None
        crossing = self.motion.crossing_s(self.policy.tolerance) or 0.0
        return float(np.median(served)) / 1e3 + interval / 2 + crossing / 2

    def _target(self, camera: Camera, light: Light) -> tuple[Camera, Light] | None:
        """The view (camera and light) to ask for when asked at ``camera``: None while a held map or one asked for
        serves it; with prefetch, once a lead is known, the first predicted view no map serves among the lead and,
        with more requests in flight allowed, one tolerance crossing further for each (None when all are served).
        """
        if self.policy.prefetch == "extrapolate":
            lead = self._lead_s()
            if lead is not None:
                assert self.policy.tolerance is not None
                step = self.motion.crossing_s(self.policy.tolerance) or 0.0
                for ahead in range(self.policy.in_flight if step > 0.0 else 1):
                    predicted = self.motion.predict(camera, lead + ahead * step)
                    if predicted is None:
                        break
                    if self._serving(predicted[0], self.policy.cell(predicted[1]), in_flight=True) is None:
                        return predicted
                else:
                    return None
        return None if self._serving(camera, self.policy.cell(light), in_flight=True) is not None else (camera, light)

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
            while self._pending():
                left = deadline - time.perf_counter()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def close(self) -> None:
        """Stop the threads (requests in flight are abandoned) and close the connections."""
        with self._cond:
            self._closed = True
            for *_, frame, t_request, request_id in sorted((*self._in_flight, *self._jobs), key=lambda j: j[4]):
                record = dict.fromkeys(RECORD_COLUMNS, "") | {
                    "request_id": request_id,
                    "frame": frame,
                    "status": "abandoned",
                }
                record |= {"error": "still in flight when the run ended", "requested_s": t_request - self._t0}
                record["latency_ms"] = (time.perf_counter() - t_request) * 1e3
                self.records.append(record)
            self._cond.notify_all()
        for thread in self._threads:
            thread.join(timeout=1.0)
        self.client.close()

    def __enter__(self) -> RemoteSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the thread ------------------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._jobs and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                job = self._jobs.popleft()
                self._in_flight.append(job)
            try:
                record, gi, wait = self._fetch(*job)
            except Exception:
                if self._closed:  # the connection was closed under a request that close() abandoned
                    return
                raise
            with self._cond:
                if self._closed:  # close() recorded it as abandoned
                    return
                self._in_flight.remove(job)
                self.records.append(record)
                if gi is not None:
                    if len(self.kept) == self.kept.maxlen:
                        self._unpicked.pop(self.kept[0][0], None)
                    cell = self.policy.cell(job[1])
                    self.kept.append((gi, cell))
                    self._cells[gi] = cell
                    self._unpicked[gi] = record
                else:
                    self._not_before = time.perf_counter() + (self.cfg.retry_after_s if wait is None else wait)
                self._cond.notify_all()

    def _fetch(
        self, camera: Camera, light: Light, frame: int, t_request: float, request_id: int
    ) -> tuple[dict[str, Any], GIMap | None, float | None]:
        """One request: its record, its map (None if it failed) and the wait the server asked for (None: none)."""
        cfg = self.cfg
        body = cfg.body(camera, light)
        record: dict[str, Any] = dict.fromkeys(RECORD_COLUMNS, "")
        record |= {"request_id": request_id, "frame": frame, "status": "ok", "requested_s": t_request - self._t0}
        headers = {"content-type": "application/json", "accept": MEDIA_TYPE}
        try:
            try:
                with self.client.stream("POST", "/v1/gimap", content=body, headers=headers) as response:
                    t_first = time.perf_counter()
                    request_line = f"POST {response.request.url.raw_path.decode()} HTTP/1.1\r\n"
                    record["bytes_up"] = len(request_line) + _header_bytes(response.request.headers) + len(body)
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
            return record, None, exc.retry_after_s
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
        return record, gi, None


# -- the client process's run ------------------------------------------------------------------------------
#: Columns of ``requests.csv``: a request's record, then what the frame that bound its map spent on it.
REQUEST_COLUMNS = (*RECORD_COLUMNS, "bound_frame", "di_ms", "bind_ms", "warp_ms", "blend_ms", "total_ms")


@dataclass(frozen=True)
class ServerInfo:
    """What the client learns from the server at start-up (``GET /v1/scenes``)."""

    #: Δp / Δθ of the server's GI tree: the client asks again once its view leaves them.
    tolerance_position: float
    tolerance_angle_deg: float
    #: Side of the scene's light cells in the tree's keys (None: its light is static, no light level).
    light_cell: float | None = None

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_position, self.tolerance_angle_deg)


def check_server(server: str, scene: str, resolution: int, codec: str, spp: int, timeout_s: float) -> ServerInfo:
    """Ask the server for its health and scenes; a :class:`~gicore.error_policy.UserError` naming the option at
    fault if it is unreachable, is not a cloud-baking server, or does not serve what the client needs."""
    from gicore.error_policy import UserError

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
        served = {s["name"]: s for s in info["scenes"]}
        resolutions, codecs, max_spp = info["resolutions"], info["codecs"], int(info["max_spp"])
        cell = served[scene].get("light_cell") if scene in served else None
        tolerance = ServerInfo(
            float(info["tolerance_position"]), float(info["tolerance_angle_deg"]), None if cell is None else float(cell)
        )
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
    #: When to ask: tolerance (only when no map held or in flight is within the server's tolerance of the view, by
    #: the GI tree's rule; -k is not used) or none (periodic: every k frames, and when the bound map leaves
    #: the tolerance).
    hold: Literal[HOLDS] = "tolerance"  # type: ignore[valid-type]
    #: Prefetch: none, or extrapolate (ask for the view the camera's recent motion reaches one measured request
    #: latency ahead; needs --hold tolerance).
    prefetch: Literal[PREFETCH] = "none"  # type: ignore[valid-type]
    #: Requests in flight at most, each on its own connection (with prefetch: successive views ahead, one
    #: tolerance crossing apart).
    in_flight: int = field(default=1, metadata={"min": 1, "max": 16})
    #: Frames per second the frames are paced to, as a display refreshes (absent: as fast as they render).
    frame_rate: float | None = field(default=None, metadata={"min": 1.0, "max": 1000.0})

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.prefetch != "none" and self.hold != "tolerance":
            raise ValueError(f"--prefetch {self.prefetch} needs --hold tolerance (it asks only when no map serves)")

    @property
    def server_name(self) -> str:
        return Path(self.scene).stem

    def policy(self, server: ServerInfo) -> RequestPolicy:
        """When to send requests to ``server`` (its tolerance and the scene's light cell)."""
        if self.hold == "none":  # the cell still names each map's light cell (perceived latency)
            return RequestPolicy(light_cell=server.light_cell, in_flight=self.in_flight)
        return RequestPolicy(server.tolerance, server.light_cell, self.prefetch, in_flight=self.in_flight)

    def remote(self, server: str, light_moves: bool) -> RemoteConfig:
        """What to ask ``server`` for: this run's maps (its resolution, codec and spp, the DI where the
        composition needs it) within its timeouts; ``light_moves``: whether the scene's light moves."""
        return RemoteConfig(
            server, self.server_name, self.resolution, self.codec, self.spp, di=self.composition == "residual",
            light_moves=light_moves, connect_timeout_s=self.connect_timeout, read_timeout_s=self.read_timeout,
            deadline_s=self.deadline,
        )  # fmt: skip


def run_client(
    cfg: CloudClientConfig, server: str, tolerance: ServerInfo, flown: PathFile | None = None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], str]:
    """Fly the run's path (``flown``; default: :func:`gicore.path_file.flown_path` of ``cfg``) composing with
    ``server``'s maps; returns (per-frame rows, per-request rows,
    the renderer that ran the per-frame raster passes: ``"mitsuba"`` when ``gl`` was asked and no GL context
    opened, see :func:`gicore.loop.open_raster`).

    The local DI and the warp's surface-mask pass use ``cfg.renderer``; the GT stays with Mitsuba. Composed
    frames of scored frames are kept and scored against the GT after the run, so the GT renders neither
    delay frames nor change when requests go out. With ``cfg.hold`` tolerance the loop asks every frame and the
    source decides (:class:`RequestPolicy`). Each row also has :data:`PERCEIVED_COLUMNS`
    (:func:`perceived_latency`).
    """
    from baseline_cloudbaking.warp import PixelWarp
    from gicore.gl import GLRenderer, RasterUnavailable
    from gicore.loop import CLIENT_LOD, LAYERS, ClientLoop, LoopConfig, open_raster, run_frames
    from gicore.path_file import flown_path
    from gicore.render import Renderer
    from gicore.scene import load_scene

    spec = load_scene(cfg.scene)
    remote = cfg.remote(server, spec.light.moves)
    renderer = Renderer(spec, cfg.resolution)
    gl = partial(GLRenderer, spec, cfg.resolution, lod=CLIENT_LOD)
    raster, used = open_raster(cfg.renderer, renderer, gl, RasterUnavailable)
    policy = cfg.policy(tolerance)
    held = policy.tolerance is not None
    loop_cfg = LoopConfig(
        every=1 if held else cfg.every, gi_fov=cfg.gi_fov_of(spec),
        max_move=None if held else tolerance.tolerance_position or None,
        max_turn=None if held else tolerance.tolerance_angle_deg or None, composition=cfg.composition, tau=cfg.tau,
        seed=cfg.seed, first_map_timeout_s=remote.connect_timeout_s + remote.deadline_s,
    )  # fmt: skip
    views = (flown or flown_path(spec, cfg, cfg.seed, cfg.local_fov_of(spec))).views(cfg.resolution)
    kept: dict[int, np.ndarray] = {}
    shown: list[tuple[float, float, GIMap | None, LightCell]] = []  # (start s, shown s, bound map, its cell)
    next_start: list[float] = []

    with RemoteSource(remote, policy) as source:
        warp = PixelWarp(LAYERS[cfg.composition])
        loop = ClientLoop(loop_cfg, raster, source, warp)

        def keep(frame: int, result) -> None:
            end = time.perf_counter()
            start = next_start[-1] if next_start else end - float(result.row["frame_ms"]) / 1e3
            gi = loop.bound
            cell = None if gi is None else source.cell_of(gi)
            shown.append((start - source.started_at, end - source.started_at, gi, cell))
            if cfg.gt_every and frame % cfg.gt_every == 0:
                kept[frame] = result.image
            if cfg.frame_rate:  # the next frame starts on the display's next refresh after this one's start
                time.sleep(max(0.0, start + 1.0 / cfg.frame_rate - time.perf_counter()))
            next_start.append(time.perf_counter())

        rows = run_frames(loop, views, None, keep)
    gi_views = [(loop.gi_camera(camera), policy.cell(light)) for camera, light in views]
    perceived = perceived_latency(gi_views, shown, tolerance.tolerance)
    for row, extra in zip(rows, perceived, strict=True):
        row |= extra
    if kept:
        ground_truth = cfg.ground_truth(renderer, spec)
        for frame, image in kept.items():
            rows[frame] |= ground_truth.score(frame, *views[frame], image)
    return rows, join_requests(source.records, rows, tuple(s for s in warp.stages if s != "bind")), used


#: Per-frame columns of how long the frame's view waited for a map that serves it (:func:`perceived_latency`).
PERCEIVED_COLUMNS = ("start_s", "shown_s", "in_tolerance", "perceived_ms", "perceived_map")


def perceived_latency(
    views: list[tuple[Camera, LightCell]],
    shown: list[tuple[float, float, GIMap | None, LightCell]],
    tol: Tolerance,
) -> list[dict[str, Any]]:
    """The perceived latency, the time from a camera move to a frame with a map within tolerance, per
    frame (every frame of a path moves its camera): :data:`PERCEIVED_COLUMNS`, i.e.

    - ``start_s`` / ``shown_s``: when the frame started (its camera moved) and when it was composed;
    - ``in_tolerance``: 1 when the map the frame shows serves its own view (the GI tree's rule, :func:`covers`);
    - ``perceived_ms``: from the frame's start to the composition of the first frame, it or a later one, showing a
      map that serves this frame's view (``""`` when no frame of the run does: censored);
    - ``perceived_map``: the frame that requested that map (its ``frame`` in ``requests.csv``).

    ``views``: per frame, the GI camera and light cell; ``shown``: per frame, its start and composition (s), the
    map it showed (None: none yet) and that map's light cell.
    """
    segments: list[tuple[int, GIMap, LightCell]] = []  # (first frame, map, cell): runs of one shown map
    at: list[int] = []  # per frame: its first segment that may serve it (the one it shows, or the next)
    for frame, (_, _, gi, cell) in enumerate(shown):
        if gi is not None and (not segments or segments[-1][1] is not gi):
            segments.append((frame, gi, cell))
        at.append(len(segments) - 1 if gi is not None else len(segments))
    held = [_viewpoint(gi.camera) for _, gi, _ in segments]
    eyes = np.array([v.eye for v in held]).reshape(-1, 3)
    dirs = np.array([v.direction for v in held]).reshape(-1, 3)
    cells = [cell for _, _, cell in segments]
    out = []
    for frame, ((camera, cell), (start, end, _, _)) in enumerate(zip(views, shown, strict=True)):
        row: dict[str, Any] = {
            "start_s": start,
            "shown_s": end,
            "in_tolerance": 0,
            "perceived_ms": "",
            "perceived_map": "",
        }
        later = [k for k in range(at[frame], len(segments)) if cells[k] == cell]
        if later and nearest(eyes[later], dirs[later], _viewpoint(camera), tol) is not None:  # some map serves it
            k = next(k for k in later if covers(segments[k][1].camera, cells[k], camera, cell, tol))
            first = max(segments[k][0], frame)
            row |= {"in_tolerance": int(first == frame), "perceived_ms": (shown[first][1] - start) * 1e3}
            row["perceived_map"] = segments[k][1].frame
        out.append(row)
    return out


def join_requests(
    records: list[dict[str, Any]], rows: list[dict[str, Any]], warp_stages: tuple[str, ...]
) -> list[dict[str, Any]]:
    """Per-request rows: each record with what the frame that bound its map spent on its local render, bind,
    warp and blend, and ``total_ms``: every stage from the request to that frame's composition, summed (the
    frame's DI included: the map is not seen before it; the wait for the next frame, ``pickup_ms``, is not a
    stage and is not in it)."""
    bound: dict[int, dict[str, Any]] = {}  # the first frame that bound each map (a held map may be bound again)
    for r in rows:
        if r["gi_new"]:
            bound.setdefault(int(r["frame"]) - int(r["gi_age_frames"]), r)
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
