"""The per-frame image buffers the project knows, with their channel counts and storage precision.

A run config names the buffers it needs; only those are rendered and stored (leave out what no
consumer needs). All are linear, HxWxC, in the frame's camera:

- ``di``: direct illumination (diffuse + glossy, with shadows), linear radiance.
- ``gt``: path-traced global illumination (the "GI map" the networks learn), linear radiance.
- ``albedo``: diffuse reflectance.
- ``normal``: shading normal in view space (OpenGL convention: camera looks down -z), zero on background.
- ``depth``: linear view depth (distance along the view axis, > 0), zero on background.
- ``position``: world-space position, zero on background.
- ``mask``: 1 where a surface was hit, else 0.

float16 loses nothing that matters for radiance (relative error 5e-4, max 65504), albedo, normals and
network-input depth. World position stays float32 because warping reprojects it.
"""

from __future__ import annotations

import numpy as np

from gicore.error_policy import UserError

CHANNELS: dict[str, int] = {"di": 3, "gt": 3, "albedo": 3, "normal": 3, "depth": 1, "position": 3, "mask": 1}
STORAGE_DTYPE: dict[str, type] = {name: np.float16 for name in CHANNELS} | {"position": np.float32}
#: The buffers of the G-buffer (AOV) pass; the rest (``di``, ``gt``) are path-traced.
GBUFFERS: tuple[str, ...] = ("albedo", "normal", "depth", "position", "mask")
#: The paper's generator input (IV.A): direct illumination + albedo + view normal + depth.
GENERATOR_INPUTS: tuple[str, ...] = ("di", "albedo", "normal", "depth")
#: What the networks learn to predict: the path-traced GI map.
TARGET = "gt"
#: What a dataset stores unless told otherwise: the generator input and its target.
DATASET_BUFFERS: tuple[str, ...] = (*GENERATOR_INPUTS, TARGET)


def check_buffer_names(names: list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Validate a buffer list (from a flag or a config file), returning it as a tuple; UserError names
    the unknown or repeated entries."""
    unknown = [n for n in names if n not in CHANNELS]
    if unknown:
        raise UserError(f"unknown buffer(s) {unknown}", f"choose from {sorted(CHANNELS)}")
    if len(set(names)) != len(names):
        raise UserError(f"buffer list {list(names)} names a buffer twice", "name each buffer once")
    return tuple(names)


#: The per-frame passes a warp reads at the shown view, rendered with that frame's DI
#: (``render_di_raster`` of both renderers): ``uv``, the structure-aware warp's bound coordinates
#: interpolated over each triangle (with ``position``, ``mask`` and ``textured``); ``mask``, the pixel-level
#: warp's surface mask. ``None``: a warp that reads no pass.
RASTERS: tuple[str, ...] = ("uv", "mask")


def check_raster(raster: str | None) -> None:
    """ValueError unless ``raster`` is one of :data:`RASTERS` or None."""
    if raster is not None and raster not in RASTERS:
        raise ValueError(f"raster must be one of {RASTERS} or None, got {raster!r}")
