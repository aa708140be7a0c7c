"""The FastAPI app of the cloud-baking server.

``create_app(settings)`` builds the app; its ``lifespan`` opens the GI tree and the scene catalog
(specs load lazily on first use, renderers are compiled on a scene's first miss) and closes the tree
on shutdown. Requests larger than ``max_body_bytes`` are refused with 413 before they are parsed;
every refused field is a 4xx whose ``detail`` names it (``{"detail": [{"loc": ["body", FIELD], "msg":
..., "type": ...}]}``, FastAPI's 422 shape without the echoed input).
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib import metadata

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from baseline_cloudbaking.bake import SceneCatalog
from baseline_cloudbaking.server.routers import gimap, health, scenes, stats
from baseline_cloudbaking.server.service import FieldError, MapService
from baseline_cloudbaking.server.settings import Settings, get_settings
from baseline_cloudbaking.store import GITree


class BodyLimit:
    """ASGI middleware: reads a request body up to ``limit`` bytes and answers 413 beyond it (whatever
    Content-Length claims), then replays the body to the app."""

    def __init__(self, app: ASGIApp, limit: int):
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        chunks, size, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            chunks.append(message.get("body", b""))
            size += len(chunks[-1])
            more = message.get("more_body", False)
            if size > self.limit:
                detail = [{"loc": ["body"], "msg": f"request body exceeds {self.limit} bytes", "type": "too_large"}]
                await JSONResponse({"detail": detail}, status_code=413)(scope, receive, send)
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


def create_app(settings: Settings | None = None) -> FastAPI:
    """The server app for ``settings`` (default: from the environment, :func:`get_settings`)."""
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if settings.render_threads is not None:
            from gicore.render import set_render_threads

            set_render_threads(settings.render_threads)
        store = GITree(settings.store, settings.budget_bytes, settings.tolerance)
        app.state.settings = settings
        app.state.store = store
        app.state.service = MapService(settings, store, SceneCatalog(settings.scenes_dir))
        try:
            yield
        finally:
            store.close()

    app = FastAPI(
        title="cloud-baking GI-map server",
        version=metadata.version("gigan-testbed"),
        description="Serves path-traced GI maps from a persistent GI tree (baseline of the GIGAN testbed, SPEC §6).",
        lifespan=lifespan,
    )
    for module in (gimap, health, stats, scenes):
        app.include_router(module.router)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(_: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's default echoes each bad input, which cannot be JSON when it is NaN or Infinity
        detail = [{"loc": list(e["loc"]), "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
        return JSONResponse({"detail": detail}, status_code=422)

    @app.exception_handler(FieldError)
    async def field_error(_: Request, exc: FieldError) -> JSONResponse:
        return JSONResponse(
            {"detail": [{"loc": ["body", exc.field], "msg": exc.message, "type": "value_error"}]},
            status_code=exc.status,
        )

    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)
    return app
