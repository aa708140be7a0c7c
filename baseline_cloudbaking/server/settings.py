"""Server settings: environment variables prefixed ``CLOUDBAKING_`` (e.g. ``CLOUDBAKING_STORE=/data/gi``),
overridden by ``cloudbaking-server`` options."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, Tolerance
from gicore.options import RESOLUTION_MAX, RESOLUTION_MIN, SPP_MAX

#: A square map resolution the server may serve (the one limit of every run, :mod:`gicore.options`).
ServedResolution = Annotated[int, Field(ge=RESOLUTION_MIN, le=RESOLUTION_MAX)]


class Settings(BaseSettings):
    """Everything the server process needs; immutable once the app is created."""

    model_config = SettingsConfigDict(env_prefix="CLOUDBAKING_", frozen=True, extra="forbid")

    store: Path = Field(Path("gi_store"), description="GI-tree folder (created if missing)")
    scenes_dir: Path | None = Field(None, description="extra scene specs (*.toml, *.json) served by file stem")
    budget_bytes: int | None = Field(
        None, gt=0, description="payload byte budget of the GI tree (LRU eviction); None: unbounded"
    )
    tolerance_position: float = Field(
        Tolerance.position,
        ge=0.0,
        allow_inf_nan=False,
        description="Δp: largest eye distance a stored map serves, scene units",
    )
    tolerance_angle_deg: float = Field(
        Tolerance.angle_deg,
        ge=0.0,
        le=180.0,
        allow_inf_nan=False,
        description="Δθ: largest view angle a stored map serves, degrees",
    )
    light_cell: float = Field(
        DEFAULT_LIGHT_CELL,
        gt=0.0,
        allow_inf_nan=False,
        description="side of a light cell (scene units) for scenes whose light moves",
    )
    resolutions: tuple[ServedResolution, ...] = Field(
        (64, 128, 256, 512), min_length=1, description="square map resolutions served"
    )
    max_spp: int = Field(256, ge=1, le=SPP_MAX, description="largest spp a request may ask for")
    max_body_bytes: int = Field(4096, ge=256, description="largest accepted request body")
    max_renderers: int = Field(4, ge=1, description="compiled (scene, resolution) renderers kept in memory")
    render_threads: int | None = Field(None, ge=1, description="Dr.Jit threads for rendering (default: all cores)")
    seed: int = Field(0, description="seeds every render's noise (with the scene and the camera)")

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_position, self.tolerance_angle_deg)


@lru_cache
def get_settings() -> Settings:
    """The settings from the environment, read once per process."""
    return Settings()
