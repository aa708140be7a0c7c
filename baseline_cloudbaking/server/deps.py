"""Typed dependencies of the routers: the app's settings and map service (set up in ``lifespan``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from baseline_cloudbaking.server.service import MapService
from baseline_cloudbaking.server.settings import Settings


# async: FastAPI runs a plain-def dependency on anyio's thread pool, a thread hop per request that cost more CPU
# than a whole hit (see service.py); these only read app state
async def app_settings(request: Request) -> Settings:
    return request.app.state.settings


async def app_service(request: Request) -> MapService:
    return request.app.state.service


SettingsDep = Annotated[Settings, Depends(app_settings)]
ServiceDep = Annotated[MapService, Depends(app_service)]
