"""``POST /v1/gimap``: the GI map at a GI camera, from the GI tree or baked for the request."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response

from baseline_cloudbaking.protocol import MEDIA_TYPE
from baseline_cloudbaking.server import errors
from baseline_cloudbaking.server.deps import ServiceDep
from baseline_cloudbaking.server.routers.maps import map_path
from baseline_cloudbaking.server.schemas import GIMapRequest
from baseline_cloudbaking.server.service import ClientGone, QueueFull, ServerStopping

router = APIRouter(prefix="/v1", tags=["gimap"])

_PAYLOAD_DOC = {
    200: {
        "description": (
            "A GI-map payload (baseline_cloudbaking.protocol): b'GIM1', u32 header length, JSON header "
            "(camera, view/proj matrices, light, codec, hit, timings_ms: lookup/read or "
            "lookup/render/denoise/encode, total), then the encoded gi [, di] and depth sections. "
            "X-GIMap-Hit says whether it came from the GI tree; Content-Location names the stored map "
            "(GET it there, cacheable forever)."
        ),
        "content": {MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
        "headers": {
            "X-GIMap-Hit": {"description": "1: served from the GI tree; 0: baked for this request", "schema": {}},
            "Content-Location": {"description": "/v1/maps/{sha} of the stored map", "schema": {"type": "string"}},
        },
    },
    409: {"description": "the store holds this scene baked from another spec"},
    **errors.ERROR_RESPONSES,
}


async def _gone(request: Request) -> None:
    """Returns when the client disconnects (the body has been read: the next message is the disconnect)."""
    while (await request.receive())["type"] != "http.disconnect":
        pass


@router.post("/gimap", response_class=Response, responses=_PAYLOAD_DOC, summary="GI map at a GI camera")
async def get_gimap(body: GIMapRequest, request: Request, service: ServiceDep) -> Response:
    """Nearest stored map within the tolerance (a hit), else path-traced + OIDN at the camera, encoded,
    stored and returned (a miss). A hit the GI tree answers from memory is served on the event loop, others on
    the hit threads (they read the index or a file); a miss waits in the bounded miss queue for the one render
    thread (503 + Retry-After when the queue is full; dropped if the client
    leaves before its turn); once the server is told to stop, misses but the one rendering get 503."""
    try:
        served = await service.answer(body, lambda: _gone(request))
    except ClientGone:
        return Response(status_code=499)  # nginx's "client closed request": nobody reads it
    except QueueFull as exc:  # answered here, not by an exception handler: a burst of misses is cheaper
        return errors.queue_full(exc)
    except ServerStopping as exc:
        return errors.stopping(exc)
    headers = {"X-GIMap-Hit": "1" if served.hit else "0", "Content-Location": map_path(served.sha)}
    return Response(content=served.payload, media_type=MEDIA_TYPE, headers=headers)
