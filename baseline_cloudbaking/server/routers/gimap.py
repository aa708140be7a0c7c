"""``POST /v1/gimap``: the GI map at a GI camera, from the GI tree or baked for the request."""

from __future__ import annotations

from fastapi import APIRouter, Response

from baseline_cloudbaking.protocol import MEDIA_TYPE
from baseline_cloudbaking.server.deps import ServiceDep
from baseline_cloudbaking.server.schemas import GIMapRequest

router = APIRouter(prefix="/v1", tags=["gimap"])

_PAYLOAD_DOC = {
    200: {
        "description": (
            "A GI-map payload (baseline_cloudbaking.protocol): b'GIM1', u32 header length, JSON header "
            "(camera, view/proj matrices, "
            "light, codec, hit, timings_ms: lookup/read or lookup/render/denoise/encode, total), then the "
            "encoded gi [, di] and depth sections."
        ),
        "content": {MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
    },
    409: {"description": "the store holds this scene baked from another spec"},
    413: {"description": "request body too large"},
    422: {"description": "a field is invalid; detail[].loc names it"},
}


@router.post("/gimap", response_class=Response, responses=_PAYLOAD_DOC, summary="GI map at a GI camera")
def get_gimap(request: GIMapRequest, service: ServiceDep) -> Response:
    """Nearest stored map within the tolerance (a hit), else path-traced + OIDN at the camera, encoded,
    stored and returned (a miss). Runs in a worker thread: a miss renders for seconds."""
    payload, extra = service.serve(request)
    return Response(content=payload, media_type=MEDIA_TYPE, headers={"X-GIMap-Hit": "1" if extra["hit"] else "0"})
