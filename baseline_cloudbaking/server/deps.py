"""Typed dependencies of the routers: the app's settings, GI tree and map service (set up in ``lifespan``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from baseline_cloudbaking.server.service import MapService
from baseline_cloudbaking.server.settings import Settings
from baseline_cloudbaking.store import GITree


def app_settings(request: Request) -> Settings:
    return request.app.state.settings


def app_store(request: Request) -> GITree:
    return request.app.state.store


def app_service(request: Request) -> MapService:
    return request.app.state.service


SettingsDep = Annotated[Settings, Depends(app_settings)]
StoreDep = Annotated[GITree, Depends(app_store)]
ServiceDep = Annotated[MapService, Depends(app_service)]
