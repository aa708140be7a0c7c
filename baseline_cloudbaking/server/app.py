"""The FastAPI app of the cloud-baking server.

``create_app(settings)`` builds the app; its ``lifespan`` opens the GI tree (scene specs load lazily on
first use, renderers are compiled on a scene's first miss) and closes the miss queue and the tree on
shutdown. Requests larger than ``max_body_bytes`` are refused with 413, and bodies slower than
``body_timeout_s`` with 408, before they are parsed; every refused field is a 4xx whose ``detail`` names
it (:mod:`~baseline_cloudbaking.server.errors`). Browsers may call the API only from the origins in
``cors_origins`` (none by default). The OpenAPI document states the limits of this server: its scenes
(an enum), resolutions, spp range and every error response.
"""

from __future__ import annotations

import asyncio
import copy
import gc
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from functools import cache
from importlib import metadata
from typing import Any

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from baseline_cloudbaking.bake import SceneCatalog
from baseline_cloudbaking.server import errors
from baseline_cloudbaking.server.routers import gimap, health, maps, scenes, stats
from baseline_cloudbaking.server.service import MapService, light_bounds, preload
from baseline_cloudbaking.server.settings import Settings, get_settings
from baseline_cloudbaking.store import GITree
from gicore.scene import SceneSpec, SceneSpecError


class BodyLimit:
    """ASGI middleware: reads a request body up to ``limit`` bytes within ``timeout_s`` and answers 413
    beyond the size (whatever Content-Length claims), 408 beyond the time; then replays the body to the app."""

    def __init__(self, app: ASGIApp, limit: int, timeout_s: float):
        self.app = app
        self.limit = limit
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        chunks: list[bytes] = []
        try:
            async with asyncio.timeout(self.timeout_s):
                refusal = await self._read(receive, chunks)
        except TimeoutError:
            msg = f"the request body did not arrive within {self.timeout_s:g} s"
            refusal = errors.error(408, ["body"], msg, "timeout", {"Connection": "close"})
        if refusal is not None:
            await refusal(scope, receive, send)
            return
        body = b"".join(chunks)
        sent = False

        async def replay() -> Message:
            nonlocal sent
            if sent:
                return await receive()
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}

        await self.app(scope, replay, send)

    async def _read(self, receive: Receive, chunks: list[bytes]) -> JSONResponse | None:
        size, more = 0, True
        while more:
            message = await receive()
            if message["type"] == "http.disconnect":
                return JSONResponse({}, status_code=499)  # nobody reads it
            chunks.append(message.get("body", b""))
            size += len(chunks[-1])
            more = message.get("more_body", False)
            if size > self.limit:
                return errors.error(413, ["body"], f"request body exceeds {self.limit} bytes", "too_large")
        return None


def request_limits(schema: dict[str, Any], settings: Settings, scenes: dict[str, SceneSpec]) -> dict[str, Any]:
    """``schema`` (FastAPI's OpenAPI document) with this server's limits on a GI-map request: the scenes it
    serves as an enum, the box holding all their light ranges, its resolutions, its spp range."""
    schema = copy.deepcopy(schema)
    props = schema["components"]["schemas"]["GIMapRequest"]["properties"]
    props["scene"]["enum"] = list(scenes)
    bounds = [light_bounds(spec, settings.light_cell) for spec in scenes.values()]
    if bounds:
        light = next(s for s in props["light"]["anyOf"] if s.get("type") == "array")
        for axis, item in enumerate(light["prefixItems"]):
            item |= {"minimum": min(b[0][axis] for b in bounds), "maximum": max(b[1][axis] for b in bounds)}
    props["resolution"] |= {"enum": list(settings.resolutions), "default": settings.default_resolution}
    props["spp"] |= {"minimum": 1, "maximum": settings.max_spp, "default": settings.default_spp}
    return schema


def create_app(settings: Settings | None = None, store: GITree | None = None) -> FastAPI:
    """The server app for ``settings`` (default: from the environment, :func:`get_settings`), serving from
    ``store`` (default: the GI tree of the settings, opened at startup); the app closes it on shutdown."""
    settings = settings or get_settings()
    catalog = SceneCatalog(settings.scenes_dir)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if settings.render_threads is not None:
            from gicore.render import set_render_threads

            set_render_threads(settings.render_threads)
        tree = store if store is not None else GITree(settings.store, settings.budget_bytes, settings.tolerance)
        service = MapService(settings, tree, catalog)
        app.state.settings = settings
        app.state.store = tree
        app.state.service = service
        preload()
        # A full collection walks every object (Mitsuba's, FastAPI's, pydantic's): 115-145 ms measured here,
        # stopping every thread, so hits saw 100+ ms stalls. Frozen objects are never walked again.
        gc.collect()
        gc.freeze()
        try:
            yield
        finally:
            service.close()
            tree.close()

    app = FastAPI(
        title="cloud-baking GI-map server",
        version=metadata.version("gigan-testbed"),
        description="Serves path-traced GI maps from a persistent GI tree (the GIGAN testbed's baseline).",
        lifespan=lifespan,
    )
    for module in (gimap, maps, health, stats, scenes):
        app.include_router(module.router)
    errors.install(app)
    base_openapi = app.openapi

    @cache  # built once: a flood of requests for it costs nothing, and the scenes served do not change
    def openapi() -> dict[str, Any]:
        specs = {}
        for name in catalog.names():
            try:
                specs[name] = catalog.get(name)
            except (SceneSpecError, FileNotFoundError):
                continue  # refused on request: not a scene this server serves
        return request_limits(base_openapi(), settings, specs)

    app.openapi = openapi  # type: ignore[method-assign]
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes, timeout_s=settings.body_timeout_s)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=list(settings.cors_origins),
            allow_methods=["GET", "POST"],
            allow_headers=["Content-Type", "If-None-Match"],
            expose_headers=["X-GIMap-Hit", "Content-Location", "ETag", "Retry-After"],
            max_age=600,
        )
    return app
