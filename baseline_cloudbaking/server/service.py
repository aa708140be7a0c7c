"""Serving GI maps: look up the GI tree, or bake (render, denoise, encode), insert and serve.

No FastAPI here. :meth:`MapService.prepare` (validation) and :meth:`MapService.find` (a hit) run on the event
loop when the GI tree can answer from memory (its viewpoints and payload cached, ``io=False``: tens of
microseconds), else on the hit threads (SQL and a file read; a thread hop costs more CPU than such a lookup).
A miss goes through :class:`MissQueue` to its own one-thread executor, so however many misses wait, no worker
thread waits with them and hits are served at once. One thread bakes because Mitsuba is not thread-safe, not
even across scenes: two threads rendering two different scenes fail inside Dr.Jit ("jit_var_sub ...
incompatible sizes", measured), and a render already uses every core. The queue is bounded: a miss beyond it
is refused at once (:class:`QueueFull`, answered 503 with Retry-After) instead of waiting without limit; a
queued miss whose client has gone is dropped before it renders. A miss re-checks the tree when its turn comes, so
concurrent identical misses bake once. Told to stop (:meth:`MapService.stop`), the queue answers waiting and new
misses :class:`ServerStopping` at once and lets the miss being rendered finish, be stored and answered within
the graceful timeout; one still rendering then is answered ServerStopping and abandoned (a render cannot be cut
short; its map is not stored).
"""

from __future__ import annotations

import asyncio
import gc
import importlib
import json
import math
import os
import statistics
import threading
import time
import zlib
from collections import OrderedDict, deque
from collections.abc import Awaitable, Callable
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import suppress
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

from baseline_cloudbaking.bake import SceneCatalog, UnknownScene, bake_map, encode_map, gi_camera, spec_sha
from baseline_cloudbaking.payload_files import payload_sha
from baseline_cloudbaking.protocol import with_header
from baseline_cloudbaking.server.schemas import GIMapRequest
from baseline_cloudbaking.server.settings import Settings
from baseline_cloudbaking.store import GITree
from baseline_cloudbaking.store_errors import StoreConflict, WouldBlock
from baseline_cloudbaking.viewpoints import MapKey, Vec3, Viewpoint, light_cell
from gicore.paths import frame_seed, light_bounds
from gicore.scene import SceneSpec, SceneSpecError

T = TypeVar("T")
#: Threads answering lookups (SQL and a file read each: a few suffice, more only contend for the GIL).
HIT_THREADS = 8

if TYPE_CHECKING:
    from gicore.render import Renderer


class QueueFull(Exception):
    """The miss queue is full: try again in ``retry_after_s`` seconds."""

    def __init__(self, retry_after_s: int) -> None:
        super().__init__(f"the miss queue is full; retry after {retry_after_s} s")
        self.retry_after_s = retry_after_s


class ClientGone(Exception):
    """The client disconnected while its miss waited."""


class ServerStopping(Exception):
    """The server is stopping: this miss was not rendered, or not finished within the graceful timeout."""

    #: Seconds a client should wait before asking again (a restarted server takes a few to start).
    retry_after_s = 5

    def __init__(self) -> None:
        super().__init__(f"the server is stopping and did not make this map; retry after {self.retry_after_s} s")


#: Niceness of the miss thread, and so of the render threads Dr.Jit starts from it (a new thread takes its
#: creator's): renders use every core, and at equal priority hits waited for CPU behind them.
MISS_NICENESS = 10


def _lower_priority() -> None:
    """Run this thread (Linux: one task) at :data:`MISS_NICENESS`; where that is not possible, as it is."""
    with suppress(OSError, AttributeError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), MISS_NICENESS)


class MissQueue:
    """Misses run one at a time on their own thread; at most ``capacity`` more wait. ``run`` refuses a miss
    beyond that (QueueFull, with a Retry-After estimated from recent miss times) and drops a waiting miss
    whose client went away (ClientGone; a miss already rendering finishes and is stored). After :meth:`stop`
    every miss but the one rendering is refused (ServerStopping)."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="miss", initializer=_lower_priority)
        self._lock = threading.Lock()
        self._pending = 0  # admitted and not finished: waiting + rendering
        self._recent_s: deque[float] = deque(maxlen=16)  # the last misses' times on the thread
        self._stopped = False
        self._deadline = asyncio.Event()  # set when the graceful timeout after stop() has passed
        self.counters = {"misses_refused": 0, "misses_dropped": 0}

    @property
    def pending(self) -> int:
        return self._pending

    @property
    def abandoned(self) -> bool:
        """A render still runs after the graceful timeout (its map will not be stored)."""
        return self._deadline.is_set() and self._pending > 0

    def stop(self, grace_s: float) -> None:
        """On the event loop: refuse new misses, drop the waiting ones, give the one rendering ``grace_s``."""
        with self._lock:
            self._stopped = True
        self._executor.shutdown(wait=False, cancel_futures=True)
        asyncio.get_running_loop().call_later(grace_s, self._deadline.set)

    def retry_after_s(self) -> int:
        """Seconds until the misses now admitted have likely run, at the median of the recent miss times (a
        first miss that compiles a renderer does not skew it); 1 to 60."""
        typical = statistics.median(self._recent_s) if self._recent_s else 1.0
        return min(60, max(1, math.ceil(self._pending * typical)))

    async def run(self, fn: Callable[[], T], gone: Callable[[], Awaitable[None]]) -> T:
        """``fn()`` on the miss thread, or QueueFull / ClientGone (when ``gone()`` finishes first)."""
        with self._lock:
            if self._stopped:
                raise ServerStopping
            if self._pending > self.capacity:  # one rendering + capacity waiting
                self.counters["misses_refused"] += 1
                raise QueueFull(self.retry_after_s())
            self._pending += 1
        future = self._executor.submit(self._timed, fn)
        future.add_done_callback(self._finished)
        result = asyncio.wrap_future(future)
        watchers = (asyncio.ensure_future(gone()), asyncio.ensure_future(self._deadline.wait()))
        try:
            await asyncio.wait((result, *watchers), return_when=asyncio.FIRST_COMPLETED)
        finally:
            for watcher in watchers:
                watcher.cancel()
        if result.done():
            if result.cancelled():  # dropped by stop() before its turn
                raise ServerStopping
            return result.result()
        if self._deadline.is_set():  # still rendering at the graceful timeout: answered now, abandoned
            result.cancel()
            raise ServerStopping
        if future.cancel():
            with self._lock:
                self.counters["misses_dropped"] += 1
        result.cancel()
        raise ClientGone

    def _timed(self, fn: Callable[[], T]) -> T:
        t0 = time.perf_counter()
        try:
            return fn()
        finally:
            with self._lock:
                self._recent_s.append(time.perf_counter() - t0)

    def _finished(self, _: Future) -> None:
        with self._lock:
            self._pending -= 1

    def close(self) -> None:
        """Wait for the miss being rendered, unless it was abandoned; drop those waiting."""
        self._executor.shutdown(wait=not self.abandoned, cancel_futures=True)


@dataclass(frozen=True)
class Prepared:
    """A validated request: its scene spec, light, GI-tree key and viewpoint, and when it arrived."""

    req: GIMapRequest
    spec: SceneSpec
    light: tuple[float, float, float]
    key: MapKey
    view: Viewpoint
    t0: float


@dataclass(frozen=True)
class Served:
    """A response: the payload with its per-request header, whether it was a hit, and the stored map's
    content address (its ``GET /v1/maps/{sha}``)."""

    payload: bytes
    hit: bool
    sha: str


def preload() -> None:
    """Import what a bake uses (Mitsuba and Dr.Jit, the denoiser, the image codecs) now: an import holds
    the GIL, and Mitsuba's took ~0.5 s during the first miss, stalling every hit."""
    import gicore.render  # noqa: F401  (sets Mitsuba's variant)

    for name in ("drjit", "pyoidn", "PIL.Image", "OpenEXR"):
        with suppress(ImportError):  # an optional one is missing: its first use says so
            importlib.import_module(name)


class FieldError(ValueError):
    """A request field the server refuses: answered with ``status`` and a detail naming ``field``."""

    def __init__(self, field: str, message: str, status: int = 422):
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message
        self.status = status


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


class MapService:
    """GI maps for requests, from ``store`` or baked from ``catalog``'s scenes (see module docstring)."""

    def __init__(self, settings: Settings, store: GITree, catalog: SceneCatalog):
        self.settings = settings
        self.store = store
        self.catalog = catalog
        self._renderers: OrderedDict[tuple[str, int], Renderer] = OrderedDict()
        self._lock = threading.Lock()
        #: lookups_threaded: requests whose lookup needed the index or a payload file (a hit thread's work)
        self.counters = {"requests": 0, "hits": 0, "misses": 0, "lookups_threaded": 0}
        self.misses = MissQueue(settings.miss_queue)
        # a plain executor: anyio's to_thread costs ~0.45 ms of CPU per call here, as much as a hit itself
        self._hits = ThreadPoolExecutor(HIT_THREADS, thread_name_prefix="hit")
        self._scenes: dict[str, SceneSpec] = {}
        self._baked: set[tuple[str, int]] = set()

    # -- scenes and renderers ---------------------------------------------------------------------
    def scene(self, name: str) -> SceneSpec:
        """The spec of scene ``name``, registered in the store (FieldError on a bad or conflicting name);
        registered once per process: a hit then costs no hashing of the spec."""
        spec = self._scenes.get(name)
        if spec is not None:
            return spec
        try:
            spec = self.catalog.get(name)
        except UnknownScene as exc:
            raise FieldError("scene", str(exc)) from None
        except (SceneSpecError, FileNotFoundError) as exc:
            raise FieldError("scene", f"the spec of scene {name!r} is invalid on this server: {exc}") from None
        try:
            self.store.register_scene(name, spec_sha(spec), self.light_cell_size(spec))
        except StoreConflict as exc:
            raise FieldError("scene", str(exc), status=409) from None
        with self._lock:
            self._scenes[name] = spec
        return spec

    def light_cell_size(self, spec: SceneSpec) -> float | None:
        """The side of a light cell for ``spec``: None (no light level) when its light is static."""
        return self.settings.light_cell if spec.light.moves else None

    def _renderer(self, name: str, spec: SceneSpec, resolution: int) -> Renderer:
        """The compiled scene at ``resolution`` (on the miss thread); least recently used ones
        beyond ``max_renderers`` are dropped."""
        from gicore.render import Renderer

        key = (name, resolution)
        with self._lock:
            renderer = self._renderers.get(key)
            if renderer is not None:
                self._renderers.move_to_end(key)
                return renderer
        try:
            renderer = Renderer(spec, resolution)
        except (OSError, ValueError) as exc:  # e.g. a user mesh file of the spec is missing or unreadable
            raise FieldError("scene", f"scene {name!r} cannot be rendered on this server: {exc}") from None
        with self._lock:
            self._renderers[key] = renderer
            while len(self._renderers) > self.settings.max_renderers:
                self._renderers.popitem(last=False)
        return renderer

    def stats(self) -> dict[str, Any]:
        """The store's statistics and this service's request counters."""
        with self._lock:
            counters = dict(self.counters)
        return self.store.stats() | counters | self.misses.counters | {"misses_pending": self.misses.pending}

    # -- serving ----------------------------------------------------------------------------------
    def _with_defaults(self, req: GIMapRequest) -> GIMapRequest:
        """``req`` with this server's defaults (as its OpenAPI document states them) for the resolution and spp
        it omits."""
        missing = {"resolution", "spp"} - req.model_fields_set
        if not missing:
            return req
        defaults = {"resolution": self.settings.default_resolution, "spp": self.settings.default_spp}
        return req.model_copy(update={name: defaults[name] for name in missing})

    def _check_bounds(self, req: GIMapRequest) -> None:
        s = self.settings
        if req.resolution not in s.resolutions:
            raise FieldError(
                "resolution", f"{req.resolution} is not served; resolutions: {', '.join(map(str, s.resolutions))}"
            )
        if req.spp > s.max_spp:
            raise FieldError("spp", f"{req.spp} exceeds this server's max_spp {s.max_spp}")

    def _light(self, req: GIMapRequest, spec: SceneSpec) -> Vec3:
        """The request's light: the rest position when omitted; else within the box the scene's light sweeps,
        widened by a light cell (a cell the sweep touches), so that requests cannot fill the GI tree with
        lights the scene never has."""
        rest = tuple(spec.light.position)
        if req.light is None:
            return rest
        if not spec.light.moves:
            if math.dist(req.light, rest) > 1e-6:
                raise FieldError("light", f"scene {req.scene!r} has a static light at {list(rest)}; omit light")
            return tuple(req.light)
        low, high = light_bounds(spec, self.settings.light_cell)
        if not all(lo <= v <= hi for v, lo, hi in zip(req.light, low, high, strict=True)):
            box = " to ".join(str([round(c, 4) for c in corner]) for corner in (low, high))
            raise FieldError("light", f"{list(req.light)} is outside the light range of scene {req.scene!r}: {box}")
        return tuple(req.light)

    def prepare(self, req: GIMapRequest, io: bool = True) -> Prepared:
        """Check ``req`` against the server's bounds and its scene (FieldError naming the field); ``io=False``:
        WouldBlock where the scene is not yet registered (that writes to the GI tree)."""
        t0 = time.perf_counter()
        req = self._with_defaults(req)
        self._check_bounds(req)
        if not io and req.scene not in self._scenes:
            raise WouldBlock
        spec = self.scene(req.scene)
        light = self._light(req, spec)
        c = req.camera
        view = Viewpoint.look_at(c.eye, c.target)
        key = MapKey(
            req.scene, light_cell(light, self.light_cell_size(spec)), req.resolution, c.fov, req.codec, req.spp, req.di
        )
        return Prepared(req, spec, light, key, view, t0)

    def lookup(self, req: GIMapRequest, io: bool = True) -> tuple[Prepared, Served | None]:
        """:meth:`prepare` and :meth:`find` in one call (one worker-thread hop per request where ``io``)."""
        p = self.prepare(req, io)
        return p, self.find(p, io)

    async def answer(self, req: GIMapRequest, gone: Callable[[], Awaitable[None]]) -> Served:
        """The response to ``req``: a hit from memory or a hit thread, else a miss through the queue
        (QueueFull, ClientGone when ``gone()`` finishes before its turn, FieldError, StoreUnwritable)."""
        try:
            p, served = self.lookup(req, io=False)
        except WouldBlock:
            with self._lock:
                self.counters["lookups_threaded"] += 1
            p, served = await asyncio.get_running_loop().run_in_executor(self._hits, self.lookup, req)
        with self._lock:  # valid requests only, as before hits were answered on the event loop
            self.counters["requests"] += 1
        if served is not None:
            return served
        return await self.misses.run(lambda: self.bake(p), gone)

    def find(self, p: Prepared, io: bool = True) -> Served | None:
        """The nearest stored map within tolerance as a response (a hit), or None (a miss); ``io=False``:
        from memory alone, else WouldBlock."""
        hit = self.store.lookup(p.key, p.view, io=io)
        if hit is None:
            return None
        with self._lock:
            self.counters["hits"] += 1
        extra = {
            "hit": True,
            "distance": {"position": hit.distance, "angle_deg": hit.angle_deg},
            "timings_ms": {"lookup": hit.lookup_ms, "read": hit.read_ms, "total": _ms(p.t0)},
        }
        return Served(with_header(hit.payload, extra, drop=() if p.req.di else ("di",)), True, hit.sha)

    def bake(self, p: Prepared) -> Served:
        """On the miss thread: the map if a miss before this one stored it, else render, encode, insert."""
        found = self.find(p)
        if found is not None:
            return found
        lookup_ms = _ms(p.t0)
        req, c = p.req, p.req.camera
        try:  # the request's camera was checked; the GI camera adds the scene's near and far planes
            camera = gi_camera(p.spec, c.eye, c.target, c.up, c.fov, req.resolution)
        except ValueError as exc:
            raise FieldError("camera", str(exc)) from None
        renderer = self._renderer(req.scene, p.spec, req.resolution)
        index = zlib.crc32(json.dumps([c.eye, c.target, c.up, c.fov, p.light]).encode())
        seed = frame_seed(self.settings.seed, f"server/{req.scene}", index)
        baked = bake_map(renderer, camera, p.light, req.spp, seed, req.di)
        t1 = time.perf_counter()
        payload = encode_map(baked, req.scene, req.codec, req.spp, p.light if p.spec.light.moves else None)
        encode_ms = _ms(t1)
        self.store.insert(p.key, p.view, payload)
        with self._lock:
            self.counters["misses"] += 1
            first_bake = (req.scene, req.resolution) not in self._baked
            self._baked.add((req.scene, req.resolution))
        if first_bake:  # what a first bake builds and imports lives long: full collections need not walk it
            gc.freeze()  # (see app.lifespan); once per renderer, so little transient garbage is kept
        timings = {
            "lookup": lookup_ms,
            "render": baked.render_ms,
            "denoise": baked.denoise_ms,
            "encode": encode_ms,
            "total": _ms(p.t0),
        }
        extra = {"hit": False, "distance": {"position": 0.0, "angle_deg": 0.0}, "timings_ms": timings}
        return Served(with_header(payload, extra), False, payload_sha(payload))

    def stop(self) -> None:
        """On the event loop, when the server is told to stop: see :meth:`MissQueue.stop`."""
        self.misses.stop(self.settings.graceful_timeout_s)

    def close(self) -> None:
        self.misses.close()
        self._hits.shutdown(wait=True)
