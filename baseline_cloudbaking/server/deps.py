"""Typed dependencies of the routers: the app's settings and map service (set up in ``lifespan``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from baseline_cloudbaking.server.service import MapService
from baseline_cloudbaking.server.settings import Settings


def app_settings(request: Request) -> Settings:
    return request.app.state.settings


def app_service(request: Request) -> MapService:
    return request.app.state.service


SettingsDep = Annotated[Settings, Depends(app_settings)]
ServiceDep = Annotated[MapService, Depends(app_service)]
