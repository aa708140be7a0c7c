"""``GET /v1/maps/{sha}``: a stored map by its content address, cacheable forever.

The URL names the payload's SHA-256, so its bytes never change: ``ETag`` is the SHA, ``Cache-Control``
says ``immutable``, and a request whose ``If-None-Match`` names it gets ``304`` with no body, so a browser
or a CDN keeps the map. The bytes are the stored payload (no per-request header fields; ``hit`` is absent).
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Path, Response
from starlette.concurrency import run_in_threadpool

from baseline_cloudbaking.protocol import MEDIA_TYPE
from baseline_cloudbaking.server.deps import ServiceDep
from baseline_cloudbaking.server.errors import ERROR_RESPONSES, error

router = APIRouter(prefix="/v1", tags=["maps"])
SHA_PATTERN = "^[0-9a-f]{64}$"
#: A year, the longest max-age caches honour; ``immutable``: never revalidate while fresh.
CACHE_CONTROL = "public, max-age=31536000, immutable"
_CACHE_HEADERS = {
    "ETag": {"description": "the map's SHA-256, quoted", "schema": {"type": "string"}},
    "Cache-Control": {"description": CACHE_CONTROL, "schema": {"type": "string"}},
}


def map_path(sha: str) -> str:
    return f"/v1/maps/{sha}"


def matches(if_none_match: str | None, etag: str) -> bool:
    """``If-None-Match`` (a list of entity tags, weak or strong, or ``*``) names ``etag`` (weak comparison)."""
    if if_none_match is None:
        return False
    tags = [t.strip() for t in if_none_match.split(",")]
    return "*" in tags or etag in (t.removeprefix("W/") for t in tags)


@router.get(
    "/maps/{sha}",
    response_class=Response,
    summary="a stored GI map by its SHA-256 (immutable)",
    responses={
        200: {
            "description": "the stored GI-map payload",
            "content": {MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
            "headers": _CACHE_HEADERS,
        },
        304: {"description": "If-None-Match names this map: the cached copy is current", "headers": _CACHE_HEADERS},
        404: {"description": "no stored map has this SHA-256 (never stored, or evicted)"},
        **ERROR_RESPONSES,
    },
)
async def get_map(
    sha: Annotated[str, Path(pattern=SHA_PATTERN, description="SHA-256 of the payload, lower-case hex")],
    service: ServiceDep,
    if_none_match: Annotated[str | None, Header(description="entity tags the client holds")] = None,
) -> Response:
    etag = f'"{sha}"'
    payload = await run_in_threadpool(service.store.payload_by_sha, sha)
    if payload is None:
        return error(404, ["path", "sha"], f"no stored map has SHA-256 {sha}", "not_found")
    headers = {"ETag": etag, "Cache-Control": CACHE_CONTROL}
    if matches(if_none_match, etag):
        return Response(status_code=304, headers=headers)
    return Response(content=payload, media_type=MEDIA_TYPE, headers=headers)
