"""Shapes beyond the procedural anatomy, for randomised training scenes and the held-out generalisation cases.

A :class:`Shape` is a kind and its numbers (plain data, so a dataset's card can record it and a shape can be made
again): primitives with sharp edges (``box``, ``plate``, ``cylinder``, ``cone``), smooth ones (``capsule``,
``ellipsoid``, ``torus``), thin shells (``tube``: a thin-walled open cylinder; ``bowl``: a thin spherical cap) and
the procedural anatomy deformed (``anatomy``: scaled per axis, twisted and bent). :meth:`Shape.mesh` builds it
y-up, tilted by ``tilt``; a scene object normalises it to its height (:meth:`gicore.mesh.Mesh.normalized`).

The renderers smooth-shade every object with vertex normals averaged over the faces around a vertex, so the
primitives are subdivided (edges at most :data:`MAX_EDGE` of their size): a face's normal then stays its own up to
a thin band along each sharp edge, instead of being blended over the whole face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gicore.anatomy import generate_anatomy
from gicore.mesh import Mesh

#: Longest edge of a subdivided primitive, as a fraction of its largest extent.
MAX_EDGE = 0.06
#: Circle sections of the round primitives.
SECTIONS = 48
SHAPE_KINDS = ("box", "plate", "cylinder", "cone", "capsule", "ellipsoid", "torus", "tube", "bowl", "anatomy")


@dataclass(frozen=True)
class Shape:
    """A shape ``kind`` (:data:`SHAPE_KINDS`) with its ``params`` (what :func:`build` of that kind reads) and a tilt
    about x then z, in degrees, applied after it is built y-up."""

    kind: str
    params: dict[str, Any] = field(default_factory=dict)
    tilt: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if self.kind not in SHAPE_KINDS:
            raise ValueError(f"unknown shape {self.kind!r}; choose one of {list(SHAPE_KINDS)}")

    def mesh(self) -> Mesh:
        """The shape's closed mesh, y-up, tilted, in its own units (a scene object normalises its height)."""
        mesh = build(self.kind, self.params)
        m = np.eye(4)
        m[:3, :3] = _rotation(2, math.radians(self.tilt[1])) @ _rotation(0, math.radians(self.tilt[0]))
        return mesh.transformed(m)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "params": dict(self.params), "tilt": list(self.tilt)}


def _rotation(axis: int, angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` radians about world axis ``axis`` (0 x, 1 y, 2 z), right-handed."""
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def _from_trimesh(mesh: Any, subdivide: bool = True) -> Mesh:
    """A trimesh primitive (z-up) as a y-up :class:`Mesh`, subdivided to :data:`MAX_EDGE` of its size."""
    import trimesh

    mesh.fix_normals()  # outward: the renderers' materials are one-sided
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    if subdivide:
        size = float(np.ptp(vertices, axis=0).max())
        vertices, faces = trimesh.remesh.subdivide_to_size(vertices, faces, MAX_EDGE * size, max_iter=12)
    z_to_y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)
    return Mesh(vertices @ z_to_y.T, faces)


def _bowl(radius: float, thickness: float, opening: float) -> Any:
    """A thin spherical cap (z-up, opening upwards): the arc from the bottom pole to ``opening`` degrees, ``thickness``
    thick, revolved about z."""
    import trimesh

    angles = np.radians(np.linspace(0.0, opening, 24))
    outer = np.stack([radius * np.sin(angles), -radius * np.cos(angles)], axis=1)
    inner = outer[::-1] * (radius - thickness) / radius
    profile = np.concatenate([outer, inner, outer[:1]])
    return trimesh.creation.revolve(profile, sections=SECTIONS)


def deformed(mesh: Mesh, scale: tuple[float, float, float], twist: float, bend: float) -> Mesh:
    """``mesh`` normalised to height 1, scaled per axis by ``scale``, twisted about y by ``twist`` degrees from its
    base to its top, and bent along x by ``bend`` times the squared height: smooth, so a closed mesh stays closed."""
    v = mesh.normalized(1.0).vertices.astype(np.float64) * np.asarray(scale, np.float64)
    y = v[:, 1] / max(float(v[:, 1].max()), 1e-12)
    a = np.radians(twist) * (y - 0.5)
    x, z = v[:, 0] * np.cos(a) + v[:, 2] * np.sin(a), -v[:, 0] * np.sin(a) + v[:, 2] * np.cos(a)
    return Mesh(np.stack([x + bend * y**2, v[:, 1], z], axis=1), mesh.faces)


def build(kind: str, p: dict[str, Any]) -> Mesh:
    """The y-up mesh of shape ``kind`` with the numbers ``p`` (see each kind's line for the keys it reads)."""
    from trimesh import creation

    if kind in ("box", "plate"):  # extents (x, y, z); a plate is a box one of whose extents is thin
        return _from_trimesh(creation.box(extents=[p["x"], p["z"], p["y"]]))
    if kind == "cylinder":  # radius, height 1
        return _from_trimesh(creation.cylinder(radius=p["radius"], height=1.0, sections=SECTIONS))
    if kind == "cone":  # radius, height 1
        return _from_trimesh(creation.cone(radius=p["radius"], height=1.0, sections=SECTIONS))
    if kind == "capsule":  # radius, length of the straight part
        return _from_trimesh(creation.capsule(height=p["length"], radius=p["radius"], count=[SECTIONS, SECTIONS]))
    if kind == "ellipsoid":  # semi-axes (x, y, z)
        sphere = creation.icosphere(subdivisions=4)
        sphere.vertices *= [p["x"], p["z"], p["y"]]
        return _from_trimesh(sphere, subdivide=False)
    if kind == "torus":  # minor radius, major radius 1
        return _from_trimesh(creation.torus(1.0, p["minor"], SECTIONS, SECTIONS // 2), subdivide=False)
    if kind == "tube":  # outer radius, wall thickness, height
        return _from_trimesh(creation.annulus(p["radius"] - p["wall"], p["radius"], p["height"], sections=SECTIONS))
    if kind == "bowl":  # thickness (radius 1), opening angle in degrees from the bottom pole
        return _from_trimesh(_bowl(1.0, p["thickness"], p["opening"]), subdivide=False)
    if kind == "anatomy":  # organ, seed, scale (x, y, z), twist (degrees), bend
        organ = generate_anatomy(p["organ"], seed=int(p["seed"]))
        return deformed(organ, tuple(p["scale"]), p["twist"], p["bend"])
    raise ValueError(f"unknown shape {kind!r}; choose one of {list(SHAPE_KINDS)}")
