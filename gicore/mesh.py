"""Triangle meshes shared by every scene object.

World convention used throughout the project: y is up, the ground plane is y = 0, lengths are in
arbitrary "scene units" and an organ is about one unit tall. `Mesh.normalized()` puts any mesh into
that convention (resting on the ground, centred on the vertical axis).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import trimesh  # imported where used: it costs every process that imports a scene ~0.5 s

MESH_SUFFIXES = (".obj", ".ply", ".stl")


@dataclass(frozen=True)
class Mesh:
    """An indexed triangle mesh.

    vertices: (N, 3) float32 positions in scene units.
    faces: (M, 3) int32 vertex indices, counter-clockwise seen from outside (normals point outward).
    Inputs are coerced to those dtypes; shapes, finiteness and index ranges are validated.
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        vertices = np.asarray(self.vertices)
        faces = np.asarray(self.faces)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ValueError(f"vertices must have shape (N, 3), got {vertices.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces must have shape (M, 3), got {faces.shape}")
        if not np.issubdtype(vertices.dtype, np.number):
            raise ValueError(f"vertices must be numeric, got dtype {vertices.dtype}")
        if faces.size and not np.issubdtype(faces.dtype, np.integer):
            raise ValueError(f"faces must hold integer indices, got dtype {faces.dtype}")
        vertices = vertices.astype(np.float32)
        if not np.all(np.isfinite(vertices)):
            raise ValueError("vertices contain NaN or infinite values")
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise ValueError(
                f"face indices must lie in [0, {len(vertices) - 1}], got range [{faces.min()}, {faces.max()}]"
            )
        # Frozen dataclass: the coerced arrays replace the inputs once, here.
        object.__setattr__(self, "vertices", np.ascontiguousarray(vertices))
        object.__setattr__(self, "faces", np.ascontiguousarray(faces, dtype=np.int32))

    @property
    def n_triangles(self) -> int:
        return int(len(self.faces))

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) array: row 0 the minimum corner, row 1 the maximum corner."""
        if len(self.vertices) == 0:
            raise ValueError("an empty mesh has no bounds")
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def vertex_normals(self) -> np.ndarray:
        """(N, 3) float32 unit normals, the area-weighted mean of the adjacent face normals.

        Vertices used by no face (or only by degenerate faces) get +y, so the result is always unit.
        """
        v = self.vertices.astype(np.float64)
        tri = v[self.faces]
        # The cross product's length is twice the face area: summing it weights by area.
        face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normals = np.zeros_like(v)
        for corner in range(3):
            for axis in range(3):
                normals[:, axis] += np.bincount(self.faces[:, corner], weights=face_n[:, axis], minlength=len(v))
        length = np.linalg.norm(normals, axis=1)
        lonely = length < 1e-20
        normals[lonely] = (0.0, 1.0, 0.0)
        length[lonely] = 1.0
        return (normals / length[:, None]).astype(np.float32)

    def is_watertight(self) -> bool:
        """True when every edge is shared by exactly two consistently wound faces.

        Judged on the stored connectivity: duplicated (unmerged) vertices count as open edges. Then every
        directed edge (a, b) of a face occurs once, and so does its reverse (b, a) in the neighbouring face.
        """
        f = self.faces.astype(np.int64)
        a, b = f.reshape(-1), np.roll(f, -1, axis=1).reshape(-1)  # each face's edges in winding order
        n = max(len(self.vertices), 1)
        directed = a * n + b
        return bool((a != b).all() and len(np.unique(directed)) == len(directed) and np.isin(b * n + a, directed).all())

    def transformed(self, matrix: np.ndarray) -> Mesh:
        """The mesh with a 4x4 homogeneous transform applied to its vertices (column vectors).

        A mirroring transform (negative determinant) also reverses the winding, so normals stay
        outward.
        """
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"transform must be a 4x4 matrix, got shape {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ValueError("transform contains NaN or infinite values")
        homogeneous = np.c_[self.vertices.astype(np.float64), np.ones(len(self.vertices))] @ m.T
        w = homogeneous[:, 3:]
        if np.any(np.abs(w) < 1e-12):
            raise ValueError("transform sends a vertex to infinity (w = 0)")
        faces = self.faces[:, ::-1] if np.linalg.det(m[:3, :3]) < 0 else self.faces
        return Mesh(homogeneous[:, :3] / w, faces)

    def normalized(self, height: float = 1.0) -> Mesh:
        """Uniformly scaled so the y-extent equals `height`, centred on x = z = 0, with min y = 0.

        The result rests on the ground plane y = 0.
        """
        if not np.isfinite(height) or height <= 0:
            raise ValueError(f"height must be positive and finite, got {height}")
        lo, hi = self.bounds.astype(np.float64)
        extent = hi[1] - lo[1]
        if extent <= 0:
            raise ValueError("mesh is flat in y; cannot normalize its height")
        scale = height / extent
        centre = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
        vertices = (self.vertices.astype(np.float64) - centre) * scale
        vertices[:, 1] = np.maximum(vertices[:, 1], 0.0)  # rounding must not sink below ground
        return Mesh(vertices, self.faces)

    def save(self, path: str | Path) -> None:
        """Write the mesh; the suffix picks the format (.ply binary by default, .obj or .stl)."""
        path = Path(path)
        suffix = path.suffix.lower() or ".ply"
        if suffix not in MESH_SUFFIXES:
            raise ValueError(f"unsupported mesh suffix {suffix!r}; use one of {MESH_SUFFIXES}")
        self._trimesh().export(path, file_type=suffix[1:])

    def _trimesh(self) -> trimesh.Trimesh:
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def load_mesh(path: str | Path) -> Mesh:
    """Load an .obj, .ply or .stl file as one mesh, with coincident vertices merged.

    FileNotFoundError or ValueError name the file when it is missing, unreadable, has no triangles or
    has a NaN/Inf vertex (which trimesh's own processing would silently drop with its faces). A file
    unchanged since its last load is not read again (the spec validation and the renderer share it).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ValueError(f"mesh file {path}: unsupported suffix {suffix!r}; use one of {MESH_SUFFIXES}")
    if not path.is_file():
        raise FileNotFoundError(f"mesh file {path}: not found")
    stat = path.stat()
    return _load_mesh(path.resolve(), stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=16)
def _load_mesh(path: Path, mtime_ns: int, size: int) -> Mesh:
    """``load_mesh`` of one version (modification time, size) of a file."""
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises a variety of types on empty or malformed files
        raise ValueError(f"mesh file {path}: cannot read a triangle mesh ({exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f"mesh file {path}: no triangles")
    bad = ~np.isfinite(np.asarray(loaded.vertices)).all(axis=1)
    if bad.any():
        raise ValueError(
            f"mesh file {path}: {int(bad.sum())} vertex(es) with NaN or Inf coordinates, e.g. vertex "
            f"{int(np.argmax(bad)) + 1}"
        )
    loaded.process()
    # OBJ seams (per-corner UVs or normals) keep split vertices unless merged explicitly.
    loaded.merge_vertices(merge_tex=True, merge_norm=True)
    return Mesh(np.asarray(loaded.vertices), np.asarray(loaded.faces))
