"""The cloud-baking client's GI source: GI maps asked from a ``cloudbaking-server`` over HTTP
(docs/architecture.md, Data flow of a cloud-baking frame).

:class:`RemoteSource` is a :class:`gicore.loop.GISource` that works in background threads over keep-alive
``httpx`` connections: :meth:`~RemoteSource.request` hands the GI camera to a thread and returns at once,
:meth:`~RemoteSource.latest` returns the newest map that has arrived (with a tolerance, the held one that
serves the view best). A failed request is logged and recorded; the loop keeps composing with the map it has.
A request's time is split into ``request``, the server's own stages, ``transfer`` and ``decode``, which sum to
its latency (:data:`RECORD_COLUMNS`). Its :class:`~baseline_cloudbaking.request_policy.RequestPolicy` decides
when to ask (:mod:`baseline_cloudbaking.request_policy`); a ``cloudbaking-client`` run is
:mod:`baseline_cloudbaking.client_run`.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import weakref
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import httpx
import numpy as np

from baseline_cloudbaking.codecs import DEFAULT_CODEC
from baseline_cloudbaking.fetch import SERVER_STAGES, Fetcher, FetcherName, open_fetcher
from baseline_cloudbaking.request_policy import (
    SEND_WHEN_ASKED,
    LightCell,
    MotionPredictor,
    RequestPolicy,
    covers,
    viewpoint_of,
)
from baseline_cloudbaking.viewpoints import nearest
from gicore.camera import Camera
from gicore.gi_map import GIMap
from gicore.paths import Light
from gicore.run_config import PathRunConfig

log = logging.getLogger("cloudbaking.client")

#: Every stage a map reports, in the order they happen.
STAGES = ("request", *SERVER_STAGES, "server_other", "transfer", "decode")
#: Columns of a request's record (``<stage>_ms`` for every stage of :data:`STAGES`).
RECORD_COLUMNS = (
    "request_id", "frame", "status", "error", "hit", "requested_s", "bytes_up", "bytes_down",
    *(f"{s}_ms" for s in STAGES), "server_ms", "transmission_ms", "latency_ms", "pickup_ms", "handoff_ms",
)  # fmt: skip


@dataclass(frozen=True)
class RemoteConfig:
    """Where the GI maps come from and what they are. ``cloudbaking-client`` makes it from its
    :class:`~baseline_cloudbaking.client_run.CloudClientConfig` (its ``remote``), so the maps asked for are the
    run's; its defaults are that config's."""

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
    #: Where requests run: process (a worker process per request slot, as a browser's web worker: the frame
    #: loop never delays them) or thread (in the client's process; what a caller without a frame loop needs).
    fetch: FetcherName = "process"
    #: Keep an 8-bit codec's map as its display values (:attr:`GIMap.display`) for a warp that decodes them itself
    #: (a GL warp, on the GPU, as the Web3D page does), instead of turning them into linear radiance on the host.
    display: bool = False

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


#: Arrived maps a source keeps to serve later views (a prefetched map arrives before its view is reached).
KEPT_MAPS = 4
#: A request handed to the workers: GI camera, light, frame, request time, request id.
Job = tuple[Camera, Light, int, float, int]


class RemoteSource:
    """GI maps from a cloud-baking server, fetched in a background thread (see the module docstring), sent
    when ``policy`` says so.

    ``records``: one dict per finished request (:data:`RECORD_COLUMNS`), in the order they finished.
    Use as a context manager, or call :meth:`close`.
    """

    name = "cloud"
    stages = STAGES

    def __init__(self, cfg: RemoteConfig, policy: RequestPolicy = SEND_WHEN_ASKED):
        self.cfg = cfg
        self.policy = policy
        self.motion = MotionPredictor(policy.history)
        self.kept: deque[tuple[GIMap, LightCell]] = deque(maxlen=KEPT_MAPS)  # arrived maps, newest last
        self._view: tuple[Camera, LightCell] | None = None  # the last view asked for
        # one fetcher per request slot, each its own connection (and, for ``process``, its own worker process)
        self._fetchers: list[Fetcher] = open_fetchers(cfg, policy.in_flight)
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
            threading.Thread(target=self._work, args=(fetcher,), name=f"gimap-requests-{i}", daemon=True)
            for i, fetcher in enumerate(self._fetchers)
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

    def latest(self, wait_s: float = 0.0) -> GIMap | None:
        """The held map that best serves the last view asked for (the newest when none does, or without a
        tolerance); with none held, waits up to ``wait_s`` for one while a request is on its way."""
        with self._cond:
            if not self.kept and wait_s > 0:
                self._cond.wait_for(lambda: self.kept or not self._pending() or self._closed, timeout=wait_s)
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
            views = [viewpoint_of(self.kept[i][0].camera) for i in mine]
            eyes, dirs = np.array([v.eye for v in views]), np.array([v.direction for v in views])
            found = nearest(eyes, dirs, viewpoint_of(camera), tol)
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
        """Each fetcher opens its keep-alive connection (``GET /v1/health``) and runs the codec once, untimed."""
        for fetcher in self._fetchers:
            error = fetcher.warm_up()
            if error is not None:
                log.warning("warm-up: GET /v1/health failed (%s); the first request will open the connection", error)
                return

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
        for fetcher in self._fetchers:  # ends the requests in flight: their threads see the source closed
            fetcher.close()
        for thread in self._threads:
            thread.join(timeout=1.0)

    def __enter__(self) -> RemoteSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the thread ------------------------------------------------------------------------------------
    def _work(self, fetcher: Fetcher) -> None:
        while True:
            with self._cond:
                while not self._jobs and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                job = self._jobs.popleft()
                self._in_flight.append(job)
            try:
                record, gi, wait = self._fetch(fetcher, *job)
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
        self, fetcher: Fetcher, camera: Camera, light: Light, frame: int, t_request: float, request_id: int
    ) -> tuple[dict[str, Any], GIMap | None, float | None]:
        """One request: its record, its map (None if it failed) and the wait the server asked for (None: none).
        ``decode`` runs from the response's last byte to the map in this process (for a ``process`` fetcher, the
        hand-over from its worker included)."""
        record: dict[str, Any] = dict.fromkeys(RECORD_COLUMNS, "")
        record |= {"request_id": request_id, "frame": frame, "requested_s": t_request - self._t0}
        fetched = fetcher.fetch(self.cfg.body(camera, light), t_request)
        arrived = time.perf_counter()
        record |= fetched.fields | {"latency_ms": (arrived - t_request) * 1e3}
        payload = fetched.payload
        if payload is None:
            status, error = record["status"], record["error"]
            log.warning("GI-map request %d (frame %d) failed: %s: %s", request_id, frame, status, error)
            return record, None, fetched.retry_after_s
        record["decode_ms"] = (arrived - fetched.t_last) * 1e3
        record["transmission_ms"] = record["request_ms"] + record["transfer_ms"]
        stages = {s: float(record[f"{s}_ms"]) for s in STAGES if record[f"{s}_ms"] != ""}
        gi = GIMap(payload.camera, payload.gi, payload.depth, payload.di, frame=frame, requested_at=t_request,
                   arrived_at=arrived, stages=stages, display=payload.display)  # fmt: skip
        return record, gi, None


def open_fetchers(cfg: RemoteConfig, n: int) -> list[Fetcher]:
    """``n`` fetchers of ``cfg.fetch``'s kind (:mod:`baseline_cloudbaking.fetch`), started together."""
    fetchers = [open_fetcher(cfg) for _ in range(n)]
    try:
        for fetcher in fetchers:
            fetcher.ready()
    except BaseException:
        for fetcher in fetchers:
            fetcher.close()
        raise
    return fetchers


class PathRequests(Protocol):
    """What :func:`request_path_maps` reads of its caller's config (a bench's, e.g. ``bench latency``'s)."""

    resolution: int
    codec: str
    spp: int
    frames: int
    orbit_frames: int
    path: Path | None
    read_timeout_s: float


def request_path_maps(
    url: str, scene: str, cfg: PathRequests, seed: int, *, residual: bool = False, off_path: bool = False
) -> dict[str, int]:
    """Ask ``url`` directly for the GI camera of every frame of the path (its ``path`` file, else the scripted
    one from ``seed``), one request at a time (``off_path``: for one camera one unit above the first, which no
    path frame is within tolerance of: it compiles the server's scene and passes and stores nothing a run
    would hit); returns the hit and miss counts."""
    from gicore.path_file import flown_path
    from gicore.scene import load_scene

    spec = load_scene(scene)
    timeout = cfg.read_timeout_s
    remote = RemoteConfig(url, Path(scene).stem, cfg.resolution, cfg.codec, cfg.spp, residual, spec.light.moves,
                          read_timeout_s=timeout, deadline_s=2 * timeout, retry_after_s=0.0,
                          fetch="thread")  # fmt: skip
    views = flown_path(spec, cfg, seed).views(cfg.resolution)[: 1 if off_path else None]
    with RemoteSource(remote) as source:
        for frame, (camera, light) in enumerate(views):
            gi_camera = camera.with_fov(spec.camera.gi_fov)
            if off_path:
                gi_camera = replace(gi_camera, origin=tuple(np.add(camera.origin, (0.0, 1.0, 0.0))))
            source.request(gi_camera, light, frame)
            source.wait(2 * timeout + 10)
    failed = [r for r in source.records if r["status"] != "ok"]
    if failed:
        raise RuntimeError(f"the server at {url} failed a request: {failed[0]['status']}: {failed[0]['error']}")
    hits = sum(int(r["hit"]) for r in source.records)
    return {"hits": hits, "misses": len(source.records) - hits}
