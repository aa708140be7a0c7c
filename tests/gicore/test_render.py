"""Mitsuba rendering: GT/DI/indirect relations, determinism, buffers, and extreme inputs
(docs/architecture.md, Mitsuba passes)."""

from __future__ import annotations

import numpy as np
import pytest

from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.metrics import all_metrics
from gicore.paths import camera_path
from gicore.render import Renderer
from gicore.tonemap import tonemap
from tests.conftest import RES

ALL_BUFFERS = ("di", "gt", "albedo", "normal", "depth", "position", "mask")


def first_camera(renderer: Renderer, **overrides) -> Camera:
    cam = camera_path(renderer.spec, 1, seed=0, resolution=renderer.resolution)[0]
    return Camera(**(cam.to_dict() | overrides))


def assert_all_finite(frame: dict[str, np.ndarray]) -> None:
    for name, arr in frame.items():
        assert np.all(np.isfinite(arr)), f"{name} has NaN/Inf"
        assert arr.dtype == np.float32, name


# -- GT, DI and indirect-only ------------------------------------------------------------------------
@pytest.mark.parametrize("fixture", ["renderer", "cornell_renderer"])
def test_gt_at_least_di_in_expectation(request, fixture):
    r = request.getfixturevalue(fixture)
    cam = first_camera(r)
    # Independent seeds: the relation must hold on average, not per pixel.
    gt = r.render_gt(cam, spp=16, seed=11)
    di = r.render_di(cam, spp=16, seed=12)
    assert np.all(gt >= 0) and np.all(di >= 0)
    assert gt.mean() > 0.01, "the test scene should be lit"
    per_channel = gt.reshape(-1, 3).mean(0) - di.reshape(-1, 3).mean(0)
    assert np.all(per_channel >= -0.01 * di.mean()), per_channel
    if fixture == "cornell_renderer":  # coloured walls give a lot of indirect light
        assert gt.mean() > 1.3 * di.mean()


@pytest.mark.parametrize("fixture", ["renderer", "cornell_renderer"])
@pytest.mark.parametrize("spp,seed", [(1, 0), (4, 7), (16, 123)])
def test_indirect_only_is_non_negative(request, fixture, spp, seed):
    r = request.getfixturevalue(fixture)
    cam = first_camera(r)
    ind = r.render_indirect(cam, spp=spp, seed=seed)
    assert ind.shape == (RES, RES, 3) and np.all(np.isfinite(ind))
    assert ind.min() >= -1e-5, f"indirect-only has negative pixels down to {ind.min()}"
    assert ind.max() > 0, "some indirect light is expected"
    # It is exactly the same-seed split GT - DI (path depth 2).
    gt = r.render_gt(cam, spp=spp, seed=seed)
    di_same = r.render_gt(cam, spp=spp, seed=seed, max_depth=2)
    np.testing.assert_allclose(ind, gt - di_same, atol=1e-6)


@pytest.mark.parametrize("fixture", ["renderer", "cornell_renderer"])
def test_different_seeds_give_negative_differences(request, fixture):
    """Why render_indirect uses one seed: with independent noise, GT - DI goes negative."""
    r = request.getfixturevalue(fixture)
    cam = first_camera(r)
    gt = r.render_gt(cam, spp=4, seed=1)
    di = r.render_di(cam, spp=4, seed=2)
    diff = gt - di
    assert diff.min() < -1e-2, f"expected clearly negative pixels, min {diff.min()}"
    # ... whereas the same seed never does.
    assert (gt - r.render_gt(cam, spp=4, seed=1, max_depth=2)).min() >= -1e-5


def test_same_seed_is_deterministic_and_seeds_differ(renderer):
    cam = first_camera(renderer)
    a = renderer.render_gt(cam, spp=2, seed=5)
    other = first_camera(renderer, fov=45.0)
    renderer.render_gt(other, spp=2, seed=9)  # move the sensor away and back
    b = renderer.render_gt(cam, spp=2, seed=5)
    c = renderer.render_gt(cam, spp=2, seed=6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


# -- buffers -------------------------------------------------------------------------------------------
def test_render_frame_returns_exactly_the_requested_buffers(renderer):
    cam = first_camera(renderer)
    frame = renderer.render_frame(cam, buffers=ALL_BUFFERS, spp=2)
    assert list(frame) == list(ALL_BUFFERS)
    channels = {"di": 3, "gt": 3, "albedo": 3, "normal": 3, "depth": 1, "position": 3, "mask": 1}
    for name, arr in frame.items():
        assert arr.shape == (RES, RES, channels[name]), name
    assert_all_finite(frame)
    mask = frame["mask"][..., 0] > 0
    assert set(np.unique(frame["mask"])) <= {0.0, 1.0}
    n = np.linalg.norm(frame["normal"][mask], axis=-1)
    np.testing.assert_allclose(n, 1.0, atol=1e-3)
    assert list(renderer.render_frame(cam, buffers=("albedo",), spp=1)) == ["albedo"]
    assert list(renderer.render_frame(cam, buffers=("gt", "di"), spp=1)) == ["gt", "di"]


def test_di_gbuffers_single_pass_equals_separate_passes(renderer):
    cam = first_camera(renderer, fov=70.0)
    one = renderer.render_di_gbuffers(cam, seed=3)
    np.testing.assert_array_equal(one["di"], renderer.render_di(cam, spp=1, seed=3))
    gb = renderer.render_gbuffers(cam, seed=3)
    assert set(one) == {"di"} | set(gb)
    for name in gb:
        np.testing.assert_array_equal(one[name], gb[name], err_msg=name)


def test_bad_render_arguments(renderer):
    cam = first_camera(renderer)
    with pytest.raises(UserError, match=r"unknown buffer\(s\) \['specular'\]"):
        renderer.render_frame(cam, buffers=("gt", "specular"))
    with pytest.raises(ValueError, match="spp"):
        renderer.render_gt(cam, spp=0)
    with pytest.raises(ValueError, match="renders"):
        renderer.render_gt(Camera(cam.origin, cam.target, width=RES * 2, height=RES * 2), spp=1)
    with pytest.raises(ValueError, match="light position"):
        renderer.render_di(cam, light=(0.0, float("nan"), 0.0))


def test_texcoords_and_uv_pass(renderer):
    cam = first_camera(renderer, fov=75.0)
    with pytest.raises(KeyError, match="nope"):
        renderer.set_texcoords("nope", np.zeros((3, 2)))
    n_vertices = len(renderer.objects[0].mesh.vertices)
    with pytest.raises(ValueError, match="n_vertices"):
        renderer.set_texcoords("ball", np.zeros((n_vertices + 1, 2)))
    renderer.set_texcoords("ball", np.tile(np.float32([0.25, 0.75]), (n_vertices, 1)))
    try:
        out = renderer.render_uv(cam)
    finally:
        renderer.set_texcoords("ball", np.zeros((n_vertices, 2), dtype=np.float32))
    assert out["uv"].shape == (RES, RES, 2) and out["position"].shape == (RES, RES, 3)
    assert out["mask"].dtype == bool and out["textured"].dtype == bool
    assert np.all(np.isfinite(out["uv"])) and np.all(np.isfinite(out["position"]))
    assert np.all(out["textured"] <= out["mask"]) and out["mask"].any()
    # Pixels on the ball carry its constant texcoords (ball = pixels whose hit lies off the ground).
    ball = (
        out["mask"] & (out["position"][..., 1] > 1e-3) & (np.linalg.norm(out["position"][..., [0, 2]], axis=-1) < 0.55)
    )
    assert ball.sum() > 10
    np.testing.assert_allclose(out["uv"][ball], np.tile([0.25, 0.75], (ball.sum(), 1)), atol=1e-5)
    # Unjittered: every hit position projects onto its own pixel centre.
    rows, cols = np.nonzero(out["mask"])
    px, w = cam.project_pixels(out["position"][rows, cols].astype(np.float64))
    assert np.all(w > 0)
    assert np.abs(px[:, 0] - (cols + 0.5)).max() < 0.01 and np.abs(px[:, 1] - (rows + 0.5)).max() < 0.01
    # Deterministic, independent of seeds.
    again = renderer.render_uv(cam)
    np.testing.assert_array_equal(again["position"], out["position"])


# -- extreme cameras -------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "overrides",
    [
        pytest.param(dict(fov=1.0), id="fov1"),
        pytest.param(dict(fov=170.0), id="fov170"),
        pytest.param(dict(near=1e-4, far=1e4), id="near1e-4_far1e4"),
        pytest.param(dict(fov=170.0, near=1e-4, far=1e4), id="fov170_near_far"),
    ],
)
def test_extreme_cameras_render_finite(renderer, overrides):
    cam = first_camera(renderer, **overrides)
    frame = renderer.render_frame(cam, buffers=ALL_BUFFERS, spp=2, seed=1)
    assert_all_finite(frame)
    assert frame["mask"].sum() > 0
    assert frame["gt"].min() >= 0 and frame["di"].min() >= 0
    mask = frame["mask"][..., 0] > 0
    assert np.all(frame["depth"][mask] > 0)


def test_supported_near_far_range_renders_like_the_default(renderer):
    """The clip range the specs accept ([NEAR_MIN, FAR_MAX]) renders the same frame as near 0.01 / far
    100 (nothing in the scene is clipped by either); outside it a Camera is refused."""
    from gicore.camera import FAR_MAX, NEAR_MIN

    ref = renderer.render_frame(first_camera(renderer), buffers=("di", "depth", "position"), spp=1, seed=3)
    for near, far in ((NEAR_MIN, 100.0), (0.01, FAR_MAX), (NEAR_MIN, FAR_MAX)):
        out = renderer.render_frame(
            first_camera(renderer, near=near, far=far), buffers=("di", "depth", "position"), spp=1, seed=3
        )
        for name in ref:
            np.testing.assert_allclose(out[name], ref[name], atol=1e-4, err_msg=f"{name} at near {near:g}, far {far:g}")
    for near, far in ((NEAR_MIN / 10, 100.0), (0.01, FAR_MAX * 10)):
        with pytest.raises(ValueError, match=r"1e-10 <= near < far <= 1e\+30"):
            first_camera(renderer, near=near, far=far)


def test_resolution_zero_is_not_the_specs(sphere_spec):
    with pytest.raises(ValueError, match="resolution must be an integer in \\[8, 2048\\], got 0"):
        Renderer(sphere_spec, 0)


@pytest.mark.parametrize("environment", ["white_plane", "cornell_box"])
def test_light_inside_a_closed_mesh_does_not_leak(make_spec, box_mesh_path, environment):
    """A closed box normalised onto the ground with a light inside it: no light reaches the camera
    outside (with its base coplanar with the floor, 611 of 4096 GT pixels were lit)."""
    cam = Camera((0.0, 1.5, 2.2), (0.0, 0.3, 0.0), fov=60.0, width=64, height=64)
    box = {"name": "box", "mesh": str(box_mesh_path), "height": 1.0}
    inside = make_spec(objects=[box], environment=environment, light={"position": [0.0, 0.5, 0.0], "intensity": 10.0})
    gt = Renderer(inside, 64).render_gt(cam, spp=64, seed=1)
    assert gt.max() == 0.0, f"{int((gt.max(-1) > 0).sum())} pixels lit by a light sealed inside the box"
    # The same light outside the box lights the scene: the camera does see the box and the floor.
    outside = make_spec(objects=[box], environment=environment, light={"position": [0.0, 1.2, 0.8], "intensity": 10.0})
    assert (Renderer(outside, 64).render_gt(cam, spp=16, seed=1).max(-1) > 1e-3).mean() > 0.5


# -- light state ------------------------------------------------------------------------------------------
@pytest.fixture
def restore_light(renderer):
    """Tests that move the shared renderer's light put it back at the spec's rest position."""
    yield renderer
    renderer.render_di(first_camera(renderer), light=tuple(renderer.spec.light.position), spp=1)


def test_light_none_means_the_specs_light_not_the_last_one(restore_light):
    """A render must not depend on what was rendered before: ``light=None`` is the spec's light."""
    r = restore_light
    cam = first_camera(r)
    rest = r.render_di(cam, light=tuple(r.spec.light.position), spp=1, seed=0)
    assert np.array_equal(r.render_di(cam, spp=1, seed=0), rest)
    moved = r.render_di(cam, light=(-1.5, 2.0, -0.5), spp=1, seed=0)
    assert not np.array_equal(moved, rest)
    np.testing.assert_array_equal(r.render_di(cam, spp=1, seed=0), rest)


# -- extreme lights ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scaled_renderers(make_spec):
    base = 12.0
    return {scale: Renderer(make_spec(light={"intensity": base * scale}), RES) for scale in (1.0, 1e4, 1e-4)}


@pytest.mark.parametrize("scale", [1e4, 1e-4])
def test_light_intensity_extremes_finite_and_linear(scaled_renderers, scale):
    ref, r = scaled_renderers[1.0], scaled_renderers[scale]
    cam = first_camera(ref)
    frame = r.render_frame(cam, buffers=("di", "gt"), spp=4, seed=3)
    assert_all_finite(frame)
    ref_frame = ref.render_frame(cam, buffers=("di", "gt"), spp=4, seed=3)
    for name in ("di", "gt"):
        # Light transport is linear in the emitted power: same seed, same paths, scaled radiance.
        np.testing.assert_allclose(frame[name], scale * ref_frame[name], rtol=1e-3, atol=1e-6 * scale)
        m = all_metrics(tonemap(frame[name]), tonemap(ref_frame[name]))
        assert all(np.isfinite(v) for k, v in m.items() if k != "psnr") and not np.isnan(m["psnr"])


@pytest.mark.parametrize(
    "light_pos",
    [
        pytest.param((0.6, 1e-4, 1.0), id="ground_1e-4"),
        pytest.param((0.0, 1e-6, 1.5), id="ground_1e-6"),
        pytest.param((0.0, 1.0 + 1e-4, 0.0), id="above_sphere_top"),
    ],
)
def test_point_light_almost_touching_a_surface(restore_light, light_pos):
    renderer = restore_light
    cam = first_camera(renderer)
    frame = renderer.render_frame(cam, light=light_pos, buffers=("di", "gt"), spp=4, seed=2)
    assert_all_finite(frame)
    assert frame["gt"].min() >= 0
    # (Above the sphere's top the sphere shadows almost everything in view; only finiteness is asked.)
    if light_pos[1] < 0.5:
        assert frame["gt"].max() > 0
    assert np.all(np.isfinite(renderer.render_indirect(cam, light=light_pos, spp=2)))


def test_point_light_hugging_the_visible_side_of_the_sphere(restore_light):
    renderer = restore_light
    cam = first_camera(renderer)
    mesh = renderer.objects[0].mesh
    normals = mesh.vertex_normals()
    # The sphere vertex facing the camera most directly, light 1e-4 off it along its normal.
    to_cam = np.asarray(cam.origin) - mesh.vertices
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    i = int(np.argmax(np.einsum("ij,ij->i", normals, to_cam)))
    light = tuple(float(x) for x in mesh.vertices[i] + 1e-4 * normals[i])
    frame = renderer.render_frame(cam, light=light, buffers=("di", "gt"), spp=4, seed=2)
    assert_all_finite(frame)
    assert frame["di"].max() > 0 and frame["gt"].max() > 0


def test_area_light_almost_touching_a_surface(make_spec):
    r = Renderer(make_spec(light={"position": [0.5, 1e-4, 1.0], "size": 0.2}), RES)
    cam = first_camera(r)
    frame = r.render_frame(cam, buffers=("di", "gt"), spp=4)
    assert_all_finite(frame)
    frame = r.render_frame(cam, light=(0.0, 1.0 + 1e-4, 0.0), buffers=("di", "gt"), spp=4)
    assert_all_finite(frame)


# -- black frames -----------------------------------------------------------------------------------------
def test_black_frame_from_tiny_light(make_spec):
    r = Renderer(make_spec(light={"intensity": 1e-30}), RES)
    frame = r.render_frame(first_camera(r), buffers=("di", "gt", "albedo"), spp=2)
    assert_all_finite(frame)
    assert frame["gt"].max() < 1e-20 and frame["gt"].min() >= 0
    black = tonemap(frame["gt"])
    m = all_metrics(black, tonemap(frame["di"]))
    assert (
        np.isfinite(m["rmse"])
        and np.isfinite(m["ssim"])
        and not np.isnan(m["psnr"])
        and 0.0 <= m["lf_error"] <= m["rmse"]
    )


def test_black_frame_from_empty_view(make_spec):
    r = Renderer(make_spec(environment="none"), RES)
    # Look up and away from the only object, into empty space.
    cam = Camera((0.0, 2.0, 3.0), (0.0, 5.0, 8.0), width=RES, height=RES)
    frame = r.render_frame(cam, buffers=ALL_BUFFERS, spp=2)
    assert_all_finite(frame)
    for name in ALL_BUFFERS:
        assert np.all(frame[name] == 0), name
    m = all_metrics(tonemap(frame["gt"]), tonemap(frame["di"]))
    assert m == {"rmse": 0.0, "psnr": float("inf"), "ssim": pytest.approx(1.0), "lf_error": 0.0}
    lit = tonemap(np.full_like(frame["gt"], 0.5))
    m = all_metrics(tonemap(frame["gt"]), lit)
    assert all(np.isfinite(v) for v in m.values())
