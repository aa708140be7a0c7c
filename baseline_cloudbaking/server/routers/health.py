"""``GET /v1/health``: liveness."""

from __future__ import annotations

from importlib import metadata

from fastapi import APIRouter

from baseline_cloudbaking.server.deps import SettingsDep
from baseline_cloudbaking.server.schemas import Health

router = APIRouter(prefix="/v1", tags=["health"])


@router.get("/health", response_model=Health, summary="liveness")
async def health(settings: SettingsDep) -> Health:
    return Health(version=metadata.version("gigan-testbed"), store=settings.store.resolve().name)
