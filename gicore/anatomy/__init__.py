"""Seeded procedural anatomy: watertight organ meshes standing on the ground plane.

`generate_anatomy(kind, seed, detail)` returns a mesh normalized to one unit tall, resting on y = 0
and centred on the vertical axis. Each kind is built as a signed distance field on a voxel grid (see
`sdf`) and meshed with marching cubes, so every mesh is closed. The same seed gives identical
arrays; `detail` scales the grid resolution, so the triangle count grows roughly as detail**2.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal, get_args

from gicore.anatomy.digestive import build_digestive
from gicore.anatomy.lungs import build_lungs
from gicore.anatomy.vessels import build_vessels
from gicore.mesh import Mesh

#: The procedural organs, as a type (scene specs validate against it) and as a tuple.
AnatomyKind = Literal["lung", "digestive", "vessels"]
ANATOMY_KINDS: tuple[str, ...] = get_args(AnatomyKind)

_BUILDERS: dict[str, Callable[[int, float], Mesh]] = dict(
    zip(ANATOMY_KINDS, (build_lungs, build_digestive, build_vessels), strict=True)
)


def generate_anatomy(kind: str, seed: int = 0, detail: float = 1.0) -> Mesh:
    """A normalized procedural organ mesh of the given kind (one of `ANATOMY_KINDS`)."""
    if kind not in _BUILDERS:
        raise ValueError(f"unknown anatomy kind {kind!r}; valid kinds: {', '.join(ANATOMY_KINDS)}")
    if not math.isfinite(detail) or detail <= 0:
        raise ValueError(f"detail must be positive and finite, got {detail}")
    return _BUILDERS[kind](int(seed), float(detail)).normalized()
