"""Mesh container, mesh I/O and procedural anatomy: validity, determinism, normalization."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from gicore.anatomy import ANATOMY_KINDS, generate_anatomy
from gicore.mesh import Mesh, load_mesh


def _signed_volume(mesh: Mesh) -> float:
    tri = mesh.vertices.astype(np.float64)[mesh.faces]
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6)


def _sphere() -> Mesh:
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    return Mesh(ico.vertices, ico.faces)


@pytest.fixture(scope="module")
def full_detail() -> dict[str, Mesh]:
    """Each kind generated once at the default detail (the expensive case)."""
    return {kind: generate_anatomy(kind, seed=0) for kind in ANATOMY_KINDS}


@pytest.mark.parametrize("kind", ANATOMY_KINDS)
def test_full_detail_is_watertight_dense_and_outward(full_detail: dict[str, Mesh], kind: str) -> None:
    mesh = full_detail[kind]
    assert mesh.is_watertight()
    assert mesh.n_triangles >= 20_000
    assert _signed_volume(mesh) > 0  # faces wound so normals point outward


@pytest.mark.parametrize("kind", ANATOMY_KINDS)
def test_full_detail_is_normalized(full_detail: dict[str, Mesh], kind: str) -> None:
    lo, hi = full_detail[kind].bounds
    assert lo[1] == 0.0
    assert hi[1] == pytest.approx(1.0, abs=1e-5)
    assert (lo[0] + hi[0]) / 2 == pytest.approx(0.0, abs=1e-5)
    assert (lo[2] + hi[2]) / 2 == pytest.approx(0.0, abs=1e-5)


@pytest.mark.parametrize("kind", ANATOMY_KINDS)
def test_lower_detail_is_coarser_and_still_watertight(full_detail: dict[str, Mesh], kind: str) -> None:
    coarse = generate_anatomy(kind, seed=0, detail=0.5)
    assert coarse.is_watertight()
    assert coarse.n_triangles < full_detail[kind].n_triangles


@pytest.mark.parametrize("kind", ANATOMY_KINDS)
def test_same_seed_same_mesh_other_seed_other_mesh(kind: str) -> None:
    a = generate_anatomy(kind, seed=3, detail=0.5)
    b = generate_anatomy(kind, seed=3, detail=0.5)
    c = generate_anatomy(kind, seed=4, detail=0.5)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    same_shape = a.vertices.shape == c.vertices.shape
    assert not (same_shape and np.allclose(a.vertices, c.vertices, atol=1e-3))


def test_unknown_kind_lists_valid_kinds() -> None:
    with pytest.raises(ValueError, match="lung, digestive, vessels"):
        generate_anatomy("liver")


@pytest.mark.parametrize("detail", [0.0, -1.0, math.nan, math.inf])
def test_bad_detail_rejected(detail: float) -> None:
    with pytest.raises(ValueError, match="detail"):
        generate_anatomy("lung", detail=detail)


def test_mesh_coerces_dtypes() -> None:
    mesh = Mesh(np.zeros((3, 3), dtype=np.float64), np.array([[0, 1, 2]], dtype=np.int64))
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int32
    assert mesh.n_triangles == 1


@pytest.mark.parametrize(
    ("vertices", "faces", "message"),
    [
        (np.zeros((3, 2)), np.array([[0, 1, 2]]), "vertices must have shape"),
        (np.zeros((3, 3)), np.array([0, 1, 2]), "faces must have shape"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), np.array([[0, 1, 2]]), "NaN"),
        (np.zeros((3, 3)), np.array([[0, 1, 3]]), "face indices"),
        (np.zeros((3, 3)), np.array([[0, -1, 2]]), "face indices"),
        (np.zeros((3, 3)), np.array([[0.0, 1.0, 2.0]]), "integer"),
    ],
)
def test_mesh_validation(vertices: np.ndarray, faces: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Mesh(vertices, faces)


def test_vertex_normals_are_unit_and_outward() -> None:
    sphere = _sphere()
    normals = sphere.vertex_normals()
    assert normals.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    radial = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    assert np.min(np.sum(normals * radial, axis=1)) > 0.99


def test_transformed_translates_and_mirroring_keeps_normals_outward() -> None:
    sphere = _sphere()
    shift = np.eye(4)
    shift[:3, 3] = (1.0, 2.0, 3.0)
    moved = sphere.transformed(shift)
    np.testing.assert_allclose(moved.bounds, sphere.bounds + (1.0, 2.0, 3.0), atol=1e-6)
    mirrored = sphere.transformed(np.diag([-1.0, 1.0, 1.0, 1.0]))
    assert _signed_volume(mirrored) > 0 and mirrored.is_watertight()
    with pytest.raises(ValueError, match="4x4"):
        sphere.transformed(np.eye(3))


def test_normalized_rests_on_ground() -> None:
    # An off-centre, stretched sphere: scale (3, 2, 1), then translate (5, -7, 2).
    moved = _sphere().transformed(np.array([[3, 0, 0, 5], [0, 2, 0, -7], [0, 0, 1, 2], [0, 0, 0, 1.0]]))
    lo, hi = moved.normalized(height=2.0).bounds
    assert lo[1] == 0.0 and hi[1] == pytest.approx(2.0, abs=1e-5)
    assert lo[0] + hi[0] == pytest.approx(0.0, abs=1e-5)
    assert lo[2] + hi[2] == pytest.approx(0.0, abs=1e-5)
    flat = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1.0]]), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="flat"):
        flat.normalized()


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
def test_save_load_round_trip(tmp_path, suffix: str) -> None:
    mesh = _sphere()
    path = tmp_path / f"sphere{suffix}"
    mesh.save(path)
    loaded = load_mesh(path)
    assert loaded.n_triangles == mesh.n_triangles
    assert len(loaded.vertices) == len(mesh.vertices)  # STL's per-face corners were merged back
    assert loaded.is_watertight()
    np.testing.assert_allclose(np.sort(loaded.vertices, axis=0), np.sort(mesh.vertices, axis=0), atol=1e-5)
    assert _signed_volume(loaded) == pytest.approx(_signed_volume(mesh), rel=1e-4)


def test_load_missing_file_names_path(tmp_path) -> None:
    path = tmp_path / "nowhere.ply"
    with pytest.raises(FileNotFoundError, match="nowhere.ply"):
        load_mesh(path)


def test_load_bad_suffix_names_suffix(tmp_path) -> None:
    path = tmp_path / "mesh.xyz"
    path.write_text("0 0 0\n")
    with pytest.raises(ValueError, match=r"\.xyz"):
        load_mesh(path)


def test_load_file_without_triangles_names_file(tmp_path) -> None:
    path = tmp_path / "points.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(ValueError, match="points.obj"):
        load_mesh(path)


def test_watertight_means_every_edge_twice_and_consistently_wound() -> None:
    """Closed and consistently wound meshes are watertight; a hole, a flipped face or a degenerate face is not
    (trimesh agrees on the hole)."""
    ico = trimesh.creation.icosphere(subdivisions=2)
    mesh = Mesh(ico.vertices, ico.faces)
    assert mesh.is_watertight() and ico.is_watertight
    holed = Mesh(ico.vertices, ico.faces[1:])
    assert not holed.is_watertight() and not trimesh.Trimesh(ico.vertices, ico.faces[1:]).is_watertight
    flipped = ico.faces.copy()
    flipped[0] = flipped[0, ::-1]
    assert not Mesh(ico.vertices, flipped).is_watertight()
    degenerate = ico.faces.copy()
    degenerate[0, 1] = degenerate[0, 0]
    assert not Mesh(ico.vertices, degenerate).is_watertight()
