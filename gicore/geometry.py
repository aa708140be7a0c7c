"""World-space geometry of a scene spec, independent of any renderer.

Every surface (anatomy, user meshes, ground plane, Cornell-box walls) becomes a triangle mesh in world
space, so the renderer and the structure-aware warp (which needs the vertices) see the same triangles.
The ground plane is deliberately two large triangles: warping must cope with triangles that reach
behind the GI camera. Meshes are cached per process (procedural anatomy takes ~0.1-0.3 s to mesh).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from gicore.anatomy import generate_anatomy
from gicore.mesh import Mesh, load_mesh
from gicore.scene import ObjectSpec, SceneSpec

WHITE = (0.8, 0.8, 0.8)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
#: Half the side of the white ground plane, and the Cornell box's half-width and height.
PLANE_HALF = 8.0
BOX_HALF, BOX_HEIGHT = 1.25, 2.5
#: Objects rest this far (scene units) above the ground, not on it. A base coplanar with the ground puts
#: a stretch of lit floor inside a closed mesh, and paths that enter the mesh through its smooth-shaded
#: walls reach it: a point light inside a closed cube lit 611 of 4096 GT pixels outside it. The gap must
#: exceed Mitsuba's ray-spawn offset (~9e-5 x (1 + |p|), |p| < 8 on the ground plane), or shadow rays from
#: the floor start inside the mesh: gaps of 1e-5 and 1e-4 still leaked (1 and 6-13 pixels), 1e-3 none
#: (white plane and Cornell box, point and area lights, 128 spp). 2e-3 is under half a pixel at 512², 60°
#: and the default camera distance of 2.4.
SEAT_GAP = 2e-3


@dataclass(frozen=True)
class SceneObject:
    """A world-space triangle mesh with its material: diffuse ``albedo`` plus, when ``roughness`` is
    set, a mild glossy coating."""

    name: str
    mesh: Mesh
    albedo: tuple[float, float, float]
    roughness: float | None = None


def object_transform(obj: ObjectSpec) -> np.ndarray:
    """Rotation about y by ``rotate_y`` degrees followed by translation to ``position``, lifted by
    :data:`SEAT_GAP` so that a mesh normalised onto y = 0 sits just above the ground."""
    a = math.radians(obj.rotate_y)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)
    m[:3, 3] = np.add(obj.position, (0.0, SEAT_GAP, 0.0))
    return m


@lru_cache(maxsize=32)
def object_mesh(obj: ObjectSpec) -> Mesh:
    """The object's world-space mesh: generated or loaded, normalised to its height, placed."""
    base = generate_anatomy(obj.anatomy, seed=obj.seed, detail=obj.detail) if obj.anatomy else load_mesh(obj.mesh)
    return base.normalized(obj.height).transformed(object_transform(obj))


def _quad(corners: np.ndarray) -> Mesh:
    """Two triangles over four corners given counter-clockwise as seen from the lit side."""
    return Mesh(np.asarray(corners, dtype=np.float32), np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32))


def environment_objects(environment: str) -> list[SceneObject]:
    """The environment's surfaces; a white-plane scene has no walls, an empty one nothing."""
    if environment == "none":
        return []
    if environment == "white_plane":
        h = PLANE_HALF
        return [SceneObject("ground", _quad([[-h, 0, -h], [-h, 0, h], [h, 0, h], [h, 0, -h]]), WHITE)]
    h, top = BOX_HALF, BOX_HEIGHT
    return [
        SceneObject("floor", _quad([[-h, 0, -h], [-h, 0, h], [h, 0, h], [h, 0, -h]]), WHITE),
        SceneObject("ceiling", _quad([[-h, top, -h], [h, top, -h], [h, top, h], [-h, top, h]]), WHITE),
        SceneObject("back", _quad([[-h, 0, -h], [h, 0, -h], [h, top, -h], [-h, top, -h]]), WHITE),
        SceneObject("left", _quad([[-h, 0, -h], [-h, top, -h], [-h, top, h], [-h, 0, h]]), RED),
        SceneObject("right", _quad([[h, 0, -h], [h, 0, h], [h, top, h], [h, top, -h]]), GREEN),
    ]


def scene_objects(spec: SceneSpec) -> list[SceneObject]:
    """All surfaces of ``spec`` in world space: its objects, then the environment's."""
    objs = [SceneObject(o.name, object_mesh(o), o.albedo, o.roughness) for o in spec.objects]
    return objs + environment_objects(spec.environment)
