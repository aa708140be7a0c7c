"""The page's settings (``/config.json``), ``POST /v1/gimap`` forwarded to cloud baking, and ``/v1/status``.

``/v1/gimap?profile=NAME&store=STATE`` goes, body and content type unchanged, to the chosen profile's server
for the chosen store (:mod:`web3d.upstreams`; absent: the first of each), through one shared
:class:`httpx.AsyncClient` (made at startup, with connect and read timeouts). The upstream's status, bytes,
content type, ``X-GIMap-Hit`` and ``Retry-After`` come back, with ``X-Profile`` and ``X-Store``. Refused
before anything is forwarded: the cloud side off or its server unavailable (503), an unknown profile or store
(422), a body that is not JSON or a Content-Type that is not ASCII (415), larger than ``max_body_bytes`` as it
arrives whatever Content-Length says (413) or slower than ``body_timeout_s`` (408). An upstream that cannot be
reached or breaks off is 502; one slower than ``read_timeout_s`` 504. A request still forwarded
``graceful_timeout_s`` after the server began to stop is answered 503 (as the cloud-baking server answers a miss
it did not finish). Every refusal here is ``{"detail": "..."}``. ``/v1/status`` is asked of the cloud at most once
a second (:class:`StatusCache`).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Awaitable
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from typing import TYPE_CHECKING, Any, TypeVar

import httpx
from fastapi import APIRouter, FastAPI, HTTPException, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from gicore.options import FRAMES_MAX
from web3d.upstreams import Cloud, Unavailable

if TYPE_CHECKING:
    from web3d.site import Site, WebSettings

router = APIRouter()
T = TypeVar("T")
#: Upstream response headers the page reads, passed through.
PASSED_HEADERS = ("X-GIMap-Hit", "Content-Location", "Retry-After")
#: The request body as OpenAPI states it (any JSON object: the cloud server validates it).
_JSON_BODY = {"requestBody": {"required": True, "content": {"application/json": {"schema": {"type": "object"}}}}}


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """The one HTTP client every forwarded request uses (its connections to the upstreams are kept alive)."""
    settings: WebSettings = app.state.site.settings
    timeout = httpx.Timeout(settings.read_timeout_s, connect=settings.connect_timeout_s)
    app.state.stopping = asyncio.Event()  # set when the server begins to stop (web3d.serve)
    app.state.status = StatusCache(app.state.site.cloud)
    try:
        async with httpx.AsyncClient(timeout=timeout) as client:
            app.state.client = client
            yield
    finally:
        app.state.status.close()


class StatusCache:
    """``cloud``'s status, asked at most once per ``max_age_s`` and shared by every request meanwhile, on a thread
    of its own: a probe of a server that does not answer takes seconds, and a flood of them on the worker pool
    would hold the workers that the static files need."""

    def __init__(self, cloud: Cloud, max_age_s: float = 1.0) -> None:
        self.cloud = cloud
        self.max_age_s = max_age_s
        self.prober = ThreadPoolExecutor(1, thread_name_prefix="gigan-web-status")
        self.asked: asyncio.Future[dict[str, dict[str, str]]] | None = None
        self.asked_at = 0.0

    async def get(self) -> dict[str, dict[str, str]]:
        asked = self.asked
        if asked is None or (asked.done() and time.monotonic() - self.asked_at >= self.max_age_s):
            self.asked_at = time.monotonic()
            asked = self.asked = asyncio.get_running_loop().run_in_executor(self.prober, self.cloud.status)
        return await asyncio.shield(asked)  # a request that goes away leaves the probe to the others

    def close(self) -> None:
        self.prober.shutdown(wait=False)


class Stopping(Exception):
    """The server began to stop, and what a request waited for did not finish within the graceful timeout."""


async def unless_stopping(app: FastAPI, call: Awaitable[T]) -> T:
    """``call``'s result; :class:`Stopping` when the server begins to stop and ``call`` is not done
    ``graceful_timeout_s`` later (uvicorn cancels it a little after that, which would answer 500)."""
    task = asyncio.ensure_future(call)
    deadline = asyncio.ensure_future(_stop_deadline(app))
    try:
        done, _ = await asyncio.wait((task, deadline), return_when=asyncio.FIRST_COMPLETED)
    finally:
        deadline.cancel()
        if not task.done():
            task.cancel()
    if task not in done:
        raise Stopping
    return task.result()


async def _stop_deadline(app: FastAPI) -> None:
    await app.state.stopping.wait()
    await asyncio.sleep(app.state.site.settings.graceful_timeout_s)


def page_config(site: Site) -> dict[str, Any]:
    """``/config.json``: the page's settings, the cloud side's profiles and stores, and the default of each; the
    most frames a recording holds (a path file's, :data:`gicore.options.FRAMES_MAX`)."""
    profiles, stores = site.cloud.profiles, site.cloud.stores
    return site.config | {
        "profiles": list(profiles),
        "profile": profiles[0] if profiles else None,
        "stores": list(stores),
        "store": stores[0] if stores else None,
        "record_frames_max": FRAMES_MAX,
    }


@router.api_route("/config.json", methods=["GET", "HEAD"], include_in_schema=False)
async def config(request: Request) -> JSONResponse:
    return JSONResponse(page_config(request.app.state.site), headers={"Cache-Control": "no-store"})


@router.api_route("/v1/status", methods=["GET", "HEAD"], include_in_schema=False)
async def status(request: Request) -> JSONResponse:
    """Which profiles and stores answer now (``idle``: started on its first request)."""
    site: Site = request.app.state.site
    state = await request.app.state.status.get()
    return JSONResponse(state | {"scene": site.config.get("scene")}, headers={"Cache-Control": "no-store"})


def _choose(kind: str, given: str | None, names: tuple[str, ...]) -> str:
    if given is None:
        return names[0]
    if given not in names:
        raise HTTPException(422, f"{kind} {given!r} is not served here; pick one of {', '.join(names)}")
    return given


async def read_body(request: Request, settings: WebSettings) -> bytes:
    """The request body, counted as it arrives (413 past the limit) and bounded in time (408)."""
    chunks: list[bytes] = []
    size = 0
    try:
        async with asyncio.timeout(settings.body_timeout_s):
            async for chunk in request.stream():
                size += len(chunk)
                if size > settings.max_body_bytes:
                    raise HTTPException(413, f"the request body exceeds {settings.max_body_bytes} bytes")
                chunks.append(chunk)
    except TimeoutError:
        msg = f"the request body did not arrive within {settings.body_timeout_s:g} s"
        raise HTTPException(408, msg, headers={"Connection": "close"}) from None
    return b"".join(chunks)


async def forward(app: FastAPI, profile: str, store: str, body: bytes, media: str) -> httpx.Response:
    """The answer of ``profile``'s server for ``store`` to ``body``. When it cannot be reached (nothing was sent),
    the cloud is asked again, which starts a child that ended anew, and a new address is tried once."""
    cloud: Cloud = app.state.site.cloud
    client: httpx.AsyncClient = app.state.client

    async def post(url: str) -> httpx.Response:
        return await unless_stopping(app, client.post(f"{url}/v1/gimap", content=body, headers={"Content-Type": media}))

    url = await unless_stopping(app, run_in_threadpool(cloud.upstream, profile, store))
    try:
        return await post(url)
    except httpx.ConnectError:
        again = await unless_stopping(app, run_in_threadpool(cloud.upstream, profile, store))
        if again == url:
            raise
        return await post(again)


@router.post("/v1/gimap", openapi_extra=_JSON_BODY)
async def gimap(request: Request, profile: str | None = None, store: str | None = None) -> Response:
    """The GI map the chosen profile's server for the chosen store answers (module docstring)."""
    site: Site = request.app.state.site
    cloud = site.cloud
    if not cloud.profiles:
        raise HTTPException(503, "the cloud side is off: start gigan-web without --no-cloud, or with --server URL")
    profile = _choose("profile", profile, cloud.profiles)
    store = _choose("store", store, cloud.stores)
    media = request.headers.get("content-type", "")
    if media.split(";")[0].strip().lower() != "application/json":
        raise HTTPException(415, f"the request body must be application/json, not {media or 'untyped'}")
    if not media.isascii():  # forwarded as it came, and an HTTP client sends only ASCII header values
        raise HTTPException(415, "the Content-Type header must be ASCII: send Content-Type: application/json")
    try:
        body = await read_body(request, site.settings)
    except ClientDisconnect:
        return Response(status_code=499)  # nobody reads it
    upstream = f"the cloud-baking server for the {store} store and profile {profile}"  # no address: it may be ours
    try:
        answer = await forward(request.app, profile, store, body, media)
    except Unavailable as exc:
        raise HTTPException(503, str(exc)) from None
    except Stopping:
        msg = "gigan-web is stopping and did not get this map: retry once it runs again"
        raise HTTPException(503, msg, headers={"Connection": "close"}) from None
    except httpx.TimeoutException:
        raise HTTPException(504, f"{upstream} did not answer in time") from None
    except httpx.HTTPError as exc:
        raise HTTPException(502, f"{upstream} failed: {type(exc).__name__} {exc}".strip()) from None
    headers = {name: answer.headers[name] for name in PASSED_HEADERS if name in answer.headers}
    headers |= {"X-Profile": profile, "X-Store": store}
    headers["Content-Type"] = answer.headers.get("Content-Type", "application/octet-stream")
    return Response(answer.content, status_code=answer.status_code, headers=headers)
