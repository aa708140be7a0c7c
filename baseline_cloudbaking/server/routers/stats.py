"""``GET /v1/stats``: GI-tree entries and bytes (per scene and codec) and request counters."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from baseline_cloudbaking.server.deps import ServiceDep

router = APIRouter(prefix="/v1", tags=["stats"])


@router.get("/stats", summary="GI-tree size and request counters")
def stats(service: ServiceDep) -> dict[str, Any]:
    """``entries``, ``bytes``, ``budget_bytes``, ``by_scene_codec``, ``scenes`` (with their light level),
    the store's ``inserts``/``evictions``/``rejected`` and this process's ``requests``/``hits``/``misses``."""
    return service.stats()
