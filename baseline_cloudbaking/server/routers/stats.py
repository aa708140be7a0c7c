"""``GET /v1/stats``: GI-tree entries and bytes (per scene and codec) and request counters."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from baseline_cloudbaking.server.deps import ServiceDep

router = APIRouter(prefix="/v1", tags=["stats"])


@router.get("/stats", summary="GI-tree size and request counters")
def stats(service: ServiceDep, request: Request) -> dict[str, Any]:
    """``entries``, ``bytes``, ``budget_bytes``, ``by_scene_codec``, ``scenes`` (with their light level),
    the store's ``inserts``/``evictions``/``rejected``, this process's ``requests``/``hits``/``misses``,
    the miss queue's ``misses_pending``/``misses_refused``/``misses_dropped`` and, under cloudbaking-server,
    ``connections_idle`` and ``connections_accepted``/``connections_drained``/``connections_refused``/
    ``connections_timed_out``."""
    out = service.stats()
    limits = getattr(request.app.state, "connections", None)
    if limits is not None:
        out |= limits.counters | {"connections_idle": limits.idle}
    return out
