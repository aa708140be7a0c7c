"""Seeded procedural anatomy: watertight organ meshes standing on the ground plane.

`generate_anatomy(kind, seed, detail)` returns a mesh normalized to one unit tall, resting on y = 0
and centred on the vertical axis. Each kind is built as a signed distance field on a voxel grid (see
`sdf`) and meshed with marching cubes, so every mesh is closed. The same seed gives identical
arrays; `detail` scales the grid resolution, so the triangle count grows roughly as detail**2.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from gicore.anatomy.digestive import build_digestive
from gicore.anatomy.lungs import build_lungs
from gicore.anatomy.vessels import build_vessels
from gicore.mesh import Mesh

ANATOMY_KINDS = ("lung", "digestive", "vessels")

_BUILDERS: dict[str, Callable[[int, float], Mesh]] = {
    "lung": build_lungs,
    "digestive": build_digestive,
    "vessels": build_vessels,
}


def generate_anatomy(kind: str, seed: int = 0, detail: float = 1.0) -> Mesh:
    """A normalized procedural organ mesh of the given kind (one of `ANATOMY_KINDS`)."""
    if kind not in _BUILDERS:
        raise ValueError(f"unknown anatomy kind {kind!r}; valid kinds: {', '.join(ANATOMY_KINDS)}")
    if not math.isfinite(detail) or detail <= 0:
        raise ValueError(f"detail must be positive and finite, got {detail}")
    return _BUILDERS[kind](int(seed), float(detail)).normalized()
