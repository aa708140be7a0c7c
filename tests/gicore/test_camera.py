"""Cameras: validation of every field, OpenGL matrices, and the half-pixel reprojection contract."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gicore.camera import FOV_MIN, Camera
from tests.conftest import RES


# -- validation -------------------------------------------------------------------------------------
@pytest.mark.parametrize("field", ["origin", "target", "up"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nan_inf_vectors_rejected_naming_field(field, bad):
    kwargs = {"origin": (0.0, 1.0, 3.0), "target": (0.0, 0.5, 0.0), "up": (0.0, 1.0, 0.0)}
    kwargs[field] = (0.0, bad, 1.0)
    with pytest.raises(ValueError, match=rf"camera\.{field}"):
        Camera(**kwargs)


@pytest.mark.parametrize("field", ["fov", "near", "far"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_nan_inf_scalars_rejected_naming_field(field, bad):
    with pytest.raises(ValueError, match=rf"camera\.{field}"):
        Camera((0, 1, 3), (0, 0, 0), **{field: bad})


def test_wrong_vector_length_rejected():
    with pytest.raises(ValueError, match=r"camera\.origin"):
        Camera((0.0, 1.0), (0.0, 0.0, 0.0))


@pytest.mark.parametrize("fov", [0.0, -10.0, 180.0, 270.0, 1e-300, FOV_MIN / 2])
def test_fov_out_of_range_names_fov(fov):
    with pytest.raises(ValueError, match=r"fov"):
        Camera((0, 1, 3), (0, 0, 0), fov=fov)


@pytest.mark.parametrize("fov", [FOV_MIN, 1.0, 20.0, 170.0, 179.0])
def test_fov_extremes_inside_range_accepted(fov):
    cam = Camera((0, 1, 3), (0, 0, 0), fov=fov)
    assert np.all(np.isfinite(cam.proj())) and np.all(np.isfinite(cam.view()))


@pytest.mark.parametrize("up", [(0.0, 1.0, 0.0), (0.0, -3.0, 0.0), (0.0, 1.0, 1e-9)])
def test_degenerate_look_at_rejected(up):
    # Looking straight down: up is parallel to the view direction.
    with pytest.raises(ValueError, match=r"up.*parallel|degenerate"):
        Camera((0.0, 5.0, 0.0), (0.0, 0.0, 0.0), up=up)


def test_zero_up_and_coincident_origin_target_rejected():
    with pytest.raises(ValueError, match=r"camera.up \[0.0, 0.0, 0.0\] has no length"):
        Camera((0, 1, 3), (0, 0, 0), up=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"origin.*target|target.*origin"):
        Camera((1, 1, 1), (1, 1, 1))


@pytest.mark.parametrize(
    "origin,target,culprit",
    [((1e308, 0.0, 0.0), (0.0, 0.0, 0.0), "origin"), ((0.0, 0.0, 1.0), (0.0, -1e31, 0.0), "target")],
)
def test_a_point_beyond_the_renderers_range_is_named(origin, target, culprit):
    """An eye at 1e308 was called 'up is parallel' (the view direction's length overflowed)."""
    with pytest.raises(ValueError, match=rf"camera.{culprit} .* lies beyond ±1e\+30") as err:
        Camera(origin, target)
    assert "parallel" not in str(err.value)
    Camera((1e29, 0.0, 0.0), (0.0, 0.0, 0.0))  # far, but within reach


@pytest.mark.parametrize("near,far", [(0.0, 1.0), (-1.0, 1.0), (2.0, 1.0), (1.0, 1.0)])
def test_bad_near_far_rejected(near, far):
    with pytest.raises(ValueError, match=r"near"):
        Camera((0, 1, 3), (0, 0, 0), near=near, far=far)


@pytest.mark.parametrize("width", [0, -4, 2.5, 10_000])
def test_bad_resolution_rejected(width):
    with pytest.raises(ValueError, match=r"camera\.width"):
        Camera((0, 1, 3), (0, 0, 0), width=width)


@pytest.mark.parametrize("field", ["width", "height"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_nan_inf_resolution_rejected_naming_field(field, bad):
    # NaN/Inf in any input is rejected with a clear error (ValueError naming the field).
    with pytest.raises(ValueError, match=rf"camera\.{field}"):
        Camera((0, 1, 3), (0, 0, 0), **{field: bad})


def test_roundtrip_dict():
    cam = Camera(
        (0.3, 1.0, 2.0), (0.0, 0.4, 0.0), up=(0.1, 1.0, 0.0), fov=75.0, near=0.1, far=50.0, width=48, height=32
    )
    assert Camera.from_dict(cam.to_dict()) == cam
    assert cam.with_fov(30.0).fov == 30.0


# -- matrices -------------------------------------------------------------------------------------
def test_view_matrix_is_gl_convention():
    cam = Camera((1.0, 2.0, 3.0), (0.0, 0.5, 0.0), up=(0.2, 1.0, 0.1))
    v = cam.view()
    # Rigid transform: orthonormal rotation with determinant +1.
    np.testing.assert_allclose(v[:3, :3] @ v[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(v[:3, :3]) == pytest.approx(1.0)
    # The eye sits at the origin of eye space, the target straight down -z.
    np.testing.assert_allclose(v @ [1.0, 2.0, 3.0, 1.0], [0, 0, 0, 1], atol=1e-12)
    t = v @ [0.0, 0.5, 0.0, 1.0]
    dist = np.linalg.norm(np.subtract((1.0, 2.0, 3.0), (0.0, 0.5, 0.0)))
    np.testing.assert_allclose(t, [0.0, 0.0, -dist, 1.0], atol=1e-12)
    # Camera +y (screen up) has a positive component along the requested up vector.
    assert np.dot(np.linalg.inv(v)[:3, 1], (0.2, 1.0, 0.1)) > 0
    # The view depth of the target is its distance.
    assert cam.view_depth(np.array([0.0, 0.5, 0.0])) == pytest.approx(dist)


def test_projection_maps_near_far_to_clip_bounds():
    cam = Camera((0, 0, 5), (0, 0, 0), near=0.5, far=20.0)
    v = cam.view()
    p = cam.proj()
    for z_eye, ndc in ((-0.5, -1.0), (-20.0, 1.0)):
        clip = p @ [0.0, 0.0, z_eye, 1.0]
        assert clip[2] / clip[3] == pytest.approx(ndc)
    # A point on the right edge of the horizontal FOV projects to u = 1.
    half = math.radians(cam.fov / 2)
    edge = np.linalg.inv(v) @ [math.tan(half) * 3.0, 0.0, -3.0, 1.0]
    uv, w = cam.project_uv(edge[:3])
    assert uv[0] == pytest.approx(1.0) and uv[1] == pytest.approx(0.5) and w > 0


def test_project_pixels_orientation():
    # Pixel row 0 is at the top of the image; column 0 on the left.
    cam = Camera((0, 0, 5), (0, 0, 0), fov=90.0, width=64, height=64)
    px, w = cam.project_pixels(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    assert np.all(w > 0)
    np.testing.assert_allclose(px[0], [32.0, 32.0])
    assert px[1, 0] > 32.0 and px[1, 1] == pytest.approx(32.0)  # +x world is right
    assert px[2, 1] < 32.0 and px[2, 0] == pytest.approx(32.0)  # +y world is up


def test_points_behind_camera_have_negative_w():
    cam = Camera((0, 0, 5), (0, 0, 0))
    _, w = cam.project_uv(np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 5.0]]))
    assert w[0] < 0 and w[1] == pytest.approx(0.0, abs=1e-12)


def test_extreme_near_far_matrices_finite():
    cam = Camera((0, 1, 3), (0, 0.5, 0), near=1e-4, far=1e4)
    assert np.all(np.isfinite(cam.view_proj()))
    uv, w = cam.project_uv(np.array([0.0, 0.5, 0.0]))
    np.testing.assert_allclose(uv, [0.5, 0.5], atol=1e-9)


# -- reprojection contract (renders) -------------------------------------------------------------------
REPROJECTION_CAMERAS = {
    "fov60_orbit": dict(origin=(0.0, 1.2, 2.4), target=(0.0, 0.5, 0.0), fov=60.0),
    "fov20_far": dict(origin=(0.5, 1.5, 5.5), target=(0.0, 0.5, 0.0), fov=20.0),
    "fov120_close": dict(origin=(0.3, 0.9, 1.4), target=(0.0, 0.4, 0.0), fov=120.0),
    "oblique_rolled": dict(origin=(1.7, 1.9, -1.6), target=(0.15, 0.35, 0.2), up=(0.35, 1.0, -0.2), fov=75.0),
    "near_far_extreme": dict(origin=(-1.2, 0.8, 2.0), target=(0.0, 0.5, 0.0), fov=90.0, near=1e-4, far=1e4),
}


@pytest.mark.parametrize("name", list(REPROJECTION_CAMERAS))
def test_position_aov_projects_back_into_its_pixel(renderer, name):
    cam = Camera(**REPROJECTION_CAMERAS[name], width=RES, height=RES)
    gb = renderer.render_gbuffers(cam, seed=3)
    mask = gb["mask"][..., 0] > 0
    assert mask.sum() > 0.2 * RES * RES, "the camera should see mostly surfaces"
    rows, cols = np.nonzero(mask)
    pts = gb["position"][rows, cols].astype(np.float64)
    px, w = cam.project_pixels(pts)
    assert np.all(w > 0)
    # Also through the exported matrices directly (what a consumer of the dataset does).
    clip = np.c_[pts, np.ones(len(pts))] @ (cam.proj() @ cam.view()).T
    uv = clip[:, :2] / (2.0 * clip[:, 3:4]) + 0.5
    np.testing.assert_allclose(np.stack([uv[:, 0] * RES, (1.0 - uv[:, 1]) * RES], -1), px, atol=1e-6)
    d_col = np.abs(px[:, 0] - (cols + 0.5))
    d_row = np.abs(px[:, 1] - (rows + 0.5))
    # float32 positions: allow a hair over half a pixel for rounding at wide FOV.
    tol = 0.5 + 2e-3
    assert d_col.max() <= tol, f"{name}: column error {d_col.max():.4f} px"
    assert d_row.max() <= tol, f"{name}: row error {d_row.max():.4f} px"


def test_depth_buffer_is_linear_view_depth(renderer):
    cam = Camera(**REPROJECTION_CAMERAS["oblique_rolled"], width=RES, height=RES)
    gb = renderer.render_gbuffers(cam)
    mask = gb["mask"][..., 0] > 0
    expected = cam.view_depth(gb["position"][mask].astype(np.float64))
    np.testing.assert_allclose(gb["depth"][mask][:, 0], expected, rtol=1e-4, atol=1e-5)
    assert np.all(gb["depth"][mask] > 0) and np.all(gb["depth"][~mask] == 0)
    # View-space normals of visible surfaces face the camera (+z in GL eye space points at the eye).
    n = gb["normal"][mask]
    pos_eye = np.c_[gb["position"][mask], np.ones(mask.sum())] @ cam.view().T
    facing = np.einsum("ij,ij->i", n, -pos_eye[:, :3])
    assert np.mean(facing > 0) > 0.95


def test_turned_and_moved_keep_the_camera_but_its_pose() -> None:
    cam = Camera((0.0, 1.0, 3.0), (0.0, 1.0, 0.0), fov=70.0, width=32, height=24)
    left = cam.turned(90.0)  # looking down -z, a quarter turn to the left looks down -x
    assert np.allclose(np.subtract(left.target, left.origin), (-3.0, 0.0, 0.0)) and left.origin == cam.origin
    right = cam.moved(right=0.5)  # its right is +x
    assert np.allclose(right.origin, (0.5, 1.0, 3.0)) and np.allclose(right.target, (0.5, 1.0, 0.0))
    back = cam.moved(back=1.0)
    assert np.allclose(back.origin, (0.0, 1.0, 4.0)) and np.allclose(back.target, (0.0, 1.0, 1.0))
    assert (left.fov, right.width, back.height) == (70.0, 32, 24)
