"""Serving GI maps: look up the GI tree, or bake (render, denoise, encode), insert and serve.

No FastAPI here: the routers call :meth:`MapService.serve` from a worker thread (plain ``def`` routes),
never on the event loop. Mitsuba is not thread-safe, not even across scenes: two threads rendering two
different scenes fail inside Dr.Jit ("jit_var_sub ... incompatible sizes", measured), so one render lock
serializes all baking (a render already uses every core). Lookups take no lock, so hits are served
while a miss renders. A miss re-checks the tree once it holds the lock, so concurrent identical misses
bake once.
"""

from __future__ import annotations

import json
import math
import threading
import time
import zlib
from collections import OrderedDict
from typing import TYPE_CHECKING, Any

from baseline_cloudbaking.bake import SceneCatalog, UnknownScene, bake_map, encode_map, gi_camera, spec_sha
from baseline_cloudbaking.protocol import with_header
from baseline_cloudbaking.server.schemas import GIMapRequest
from baseline_cloudbaking.server.settings import Settings
from baseline_cloudbaking.store import GITree, MapKey, StoreConflict, Viewpoint, light_cell
from gicore.paths import frame_seed
from gicore.scene import SceneSpec, SceneSpecError

if TYPE_CHECKING:
    from gicore.render import Renderer


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
        self._render_lock = threading.Lock()
        self._lock = threading.Lock()
        self.counters = {"requests": 0, "hits": 0, "misses": 0}

    # -- scenes and renderers ---------------------------------------------------------------------
    def scene(self, name: str) -> SceneSpec:
        """The spec of scene ``name``, registered in the store (FieldError on a bad or conflicting name)."""
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
        return spec

    def light_cell_size(self, spec: SceneSpec) -> float | None:
        """The side of a light cell for ``spec``: None (no light level) when its light is static."""
        return self.settings.light_cell if spec.light.moves else None

    def _renderer(self, name: str, spec: SceneSpec, resolution: int) -> Renderer:
        """The compiled scene at ``resolution`` (caller holds the render lock); least recently used ones
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
        return self.store.stats() | counters

    # -- serving ----------------------------------------------------------------------------------
    def _check_bounds(self, req: GIMapRequest) -> None:
        s = self.settings
        if req.resolution not in s.resolutions:
            raise FieldError(
                "resolution", f"{req.resolution} is not served; resolutions: {', '.join(map(str, s.resolutions))}"
            )
        if req.spp > s.max_spp:
            raise FieldError("spp", f"{req.spp} exceeds this server's max_spp {s.max_spp}")

    def _light(self, req: GIMapRequest, spec: SceneSpec) -> tuple[float, float, float]:
        rest = tuple(spec.light.position)
        if req.light is None:
            return rest
        if not spec.light.moves and math.dist(req.light, rest) > 1e-6:
            raise FieldError("light", f"scene {req.scene!r} has a static light at {list(rest)}; omit light")
        return tuple(req.light)

    def serve(self, req: GIMapRequest) -> tuple[bytes, dict[str, Any]]:
        """The payload for ``req`` and its header additions (hit flag, timings, distance)."""
        t0 = time.perf_counter()
        self._check_bounds(req)
        spec = self.scene(req.scene)
        light = self._light(req, spec)
        c = req.camera
        try:
            camera = gi_camera(spec, c.eye, c.target, c.up, c.fov, req.resolution)
        except ValueError as exc:
            raise FieldError("camera", str(exc)) from None
        view = Viewpoint.look_at(c.eye, c.target)
        key = MapKey(
            req.scene, light_cell(light, self.light_cell_size(spec)), req.resolution, c.fov, req.codec, req.spp, req.di
        )
        with self._lock:
            self.counters["requests"] += 1
        hit = self.store.lookup(key, view)
        if hit is None:
            with self._render_lock:
                hit = self.store.lookup(key, view)  # baked by a concurrent request while we waited?
                if hit is None:
                    return self._bake(req, spec, camera, light, key, view, t0)
        with self._lock:
            self.counters["hits"] += 1
        extra = {
            "hit": True,
            "distance": {"position": hit.distance, "angle_deg": hit.angle_deg},
            "timings_ms": {"lookup": hit.lookup_ms, "read": hit.read_ms, "total": _ms(t0)},
        }
        return with_header(hit.payload, extra, drop=() if req.di else ("di",)), extra

    def _bake(
        self, req: GIMapRequest, spec: SceneSpec, camera, light, key: MapKey, view: Viewpoint, t0: float
    ) -> tuple[bytes, dict[str, Any]]:
        """Render, encode and insert the map for ``req`` (the render lock is held)."""
        lookup_ms = _ms(t0)
        renderer = self._renderer(req.scene, spec, req.resolution)
        c = req.camera
        index = zlib.crc32(json.dumps([c.eye, c.target, c.up, c.fov, light]).encode())
        baked = bake_map(
            renderer, camera, light, req.spp, frame_seed(self.settings.seed, f"server/{req.scene}", index), req.di
        )
        t1 = time.perf_counter()
        payload = encode_map(baked, req.scene, req.codec, req.spp, light if spec.light.moves else None)
        encode_ms = _ms(t1)
        self.store.insert(key, view, payload)
        with self._lock:
            self.counters["misses"] += 1
        timings = {
            "lookup": lookup_ms,
            "render": baked.render_ms,
            "denoise": baked.denoise_ms,
            "encode": encode_ms,
            "total": _ms(t0),
        }
        extra = {"hit": False, "distance": {"position": 0.0, "angle_deg": 0.0}, "timings_ms": timings}
        return with_header(payload, extra), extra
