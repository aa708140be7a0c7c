"""Structure-aware (Alg. 1) and pixel-level 3D image warping: identity, benefit over not warping, the
ground plane behind the GI camera, occlusion, and extreme cameras (docs/architecture.md, Structure-aware warping)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from baseline_cloudbaking.warp import PixelWarp, PointCloud
from gicore.camera import Camera
from gicore.fill import push_pull
from gicore.gi_map import GIMap, texel_depth
from gicore.loop import ClientLoop, LoopConfig, PasteWarp, SynchronousSource
from gicore.metrics import all_metrics, ssim
from gicore.tonemap import tonemap
from gigan_local.client import GTSource
from gigan_local.warp import GITexture, StructureAwareWarp

RES = 48
METHODS = ("structure", "pixel")
LIGHT = (0.8, 2.6, 1.2)
EYE, TARGET = (0.0, 1.2, 2.4), (0.0, 0.5, 0.0)


@pytest.fixture(scope="module")
def warp_renderer(make_spec):
    """Sphere and box on the 2-triangle ground plane, at RES²."""
    from gicore.render import Renderer

    return Renderer(make_spec(with_box=True), RES)


def cam(origin=EYE, target=TARGET, fov=60.0, **kw) -> Camera:
    return Camera(origin, target, fov=fov, width=RES, height=RES, **kw)


def yawed(camera: Camera, degrees: float) -> Camera:
    """``camera`` turned about the vertical axis through its origin."""
    a = math.radians(degrees)
    d = np.subtract(camera.target, camera.origin)
    rot = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    return Camera(
        camera.origin,
        tuple(np.add(camera.origin, rot @ d)),
        fov=camera.fov,
        near=camera.near,
        far=camera.far,
        width=RES,
        height=RES,
    )


def warp_both(method: str, renderer, image: np.ndarray, depth: np.ndarray, gi_cam: Camera, local: Camera):
    """(warped image, valid mask, the local uv pass) by ``method`` (pixel-level without hole filling)."""
    if method == "structure":
        warper = StructureAwareWarp(renderer)
        warper.bind_texture(GITexture.build(gi_cam, image, depth))
        uv_pass = renderer.render_uv(local)  # after bind: the pass interpolates the bound coordinates
        out, valid, timings = warper.resample(uv_pass)
    else:
        uv_pass = renderer.render_uv(local)
        out, valid, timings = PointCloud(image, depth, gi_cam).splat(local, target_mask=uv_pass["mask"], fill=False)
    assert timings and all(t >= 0.0 for t in timings.values())
    return out, valid, uv_pass


# -- identity ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
def test_identical_cameras_give_the_identity(warp_renderer, method):
    c = cam()
    image = np.random.default_rng(0).uniform(0.0, 4.0, size=(RES, RES, 6)).astype(np.float32)  # neighbours differ
    out, valid, uv_pass = warp_both(method, warp_renderer, image, texel_depth(warp_renderer, c), c, c)
    assert valid[uv_pass["mask"]].mean() > 0.97
    assert np.max(np.abs(out[valid] - image[valid])) <= 1e-5


# -- warping beats not warping --------------------------------------------------------------------------
class _Fixed(SynchronousSource):
    """A GI source that always returns the same map (the GT GI map of v_{t-1})."""

    name = "fixed"
    stages = GTSource.stages

    def __init__(self, gi: GIMap):
        super().__init__()
        self.gi = gi

    def produce(self, camera, light, frame):
        return self.gi


@pytest.fixture(scope="module")
def gt_source(warp_renderer):
    return GTSource(warp_renderer, spp=32, denoise=True, seed=3, cache={})


@pytest.mark.parametrize("motion", ["rotate5", "rotate15", "translate"])
@pytest.mark.parametrize("method", METHODS)
def test_warping_beats_not_warping(warp_renderer, gt_source, method, motion):
    before = cam()
    after = {
        "rotate5": yawed(before, 5.0),
        "rotate15": yawed(before, 15.0),
        "translate": cam(origin=(0.35, 1.2, 2.3), target=(0.35, 0.5, -0.1)),
    }[motion]
    gt = gt_source.produce(after, LIGHT, 1).radiance

    def composed(warp: str) -> np.ndarray:
        gi_fov = 90.0 if warp != "none" else before.fov  # pasting needs a map made at the local FOV
        w = {"structure": StructureAwareWarp(warp_renderer), "pixel": PixelWarp(), "none": PasteWarp()}[warp]
        client = ClientLoop(
            LoopConfig(every=100, gi_fov=gi_fov),
            warp_renderer,
            _Fixed(gt_source.produce(before.with_fov(gi_fov), LIGHT, 0)),
            w,
        )
        client.step(0, before, LIGHT)
        return client.step(1, after, LIGHT).image

    warped, pasted = ssim(tonemap(composed(method)), tonemap(gt)), ssim(tonemap(composed("none")), tonemap(gt))
    assert warped > pasted + 0.01, (warped, pasted)


# -- ground plane spanning w = 0 ---------------------------------------------------------------------
def test_plane_behind_gi_camera_matches_per_pixel_projection(warp_renderer):
    gi_cam = cam(origin=(0.0, 0.15, 3.0), target=(0.0, 0.15, 0.0), fov=90.0)  # low, looking along the plane
    ground = next(o for o in warp_renderer.objects if o.name == "ground")
    _, w_vertices = gi_cam.project_uv(ground.mesh.vertices)
    assert (w_vertices <= 0).any() and (w_vertices > 0).any(), "the plane's triangles must span w = 0"

    local = yawed(cam(origin=(0.1, 0.2, 2.8), target=(0.1, 0.2, 0.0)), 8.0)
    depth = texel_depth(warp_renderer, gi_cam)
    warper = StructureAwareWarp(warp_renderer)
    warper.bind_texture(GITexture.build(gi_cam, np.ones((RES, RES, 3), np.float32), depth))
    uv_pass = warp_renderer.render_uv(local)
    coords, w = warper.texel_coords(uv_pass)
    expected, w_ref = gi_cam.project_pixels(uv_pass["position"].astype(np.float64))
    on_ground = uv_pass["textured"] & (np.abs(uv_pass["position"][..., 1]) < 1e-4)
    front = on_ground & (w_ref > gi_cam.near)
    assert front.sum() > RES * RES // 10, "the local view must see much of the plane"
    assert np.all(np.isfinite(coords)) and np.all(np.isfinite(w))
    np.testing.assert_allclose(w[front], w_ref[front], rtol=1e-5)
    assert np.max(np.abs(coords[front] - expected[front])) <= 1.0

    out, valid, _ = warper.resample(uv_pass)
    assert np.all(np.isfinite(out)) and valid[front].mean() > 0.9


# -- occlusion ---------------------------------------------------------------------------------------------
def test_occluded_surface_is_invalid_and_gets_the_fallback(warp_renderer):
    gi_cam = cam(origin=(0.0, 0.5, 2.0), target=(0.0, 0.5, 0.0), fov=90.0)  # level with the ball
    local = cam(origin=(1.5, 1.5, 0.5), target=(0.0, 0.0, -0.8))  # from above: sees ground the ball hides
    depth = texel_depth(warp_renderer, gi_cam)
    warper = StructureAwareWarp(warp_renderer)
    # a GI map of 5 whose indirect part is 1 everywhere: the fallback gives base + 1 exactly
    warper.bind_texture(
        GITexture.build(
            gi_cam, np.full((RES, RES, 3), 5.0, np.float32), depth, indirect=np.ones((RES, RES, 3), np.float32)
        )
    )
    uv_pass = warp_renderer.render_uv(local)
    base = np.random.default_rng(4).uniform(size=(RES, RES, 3)).astype(np.float32)
    out, valid, timings = warper.resample(uv_pass, base=base)
    assert set(timings) == {"project", "depth_test", "lookup", "fill"}
    np.testing.assert_allclose(out[valid], 5.0, rtol=1e-6)
    hole = uv_pass["mask"] & ~valid
    np.testing.assert_allclose(out[hole], base[hole] + 1.0, rtol=1e-6)
    assert np.all(out[~uv_pass["mask"]] == 0.0)

    # Ground truth: a local pixel is clearly occluded when all four GI texels around its projection hold
    # something at least 20 % nearer to the GI camera than the pixel's own point.
    px, w = gi_cam.project_pixels(uv_pass["position"].astype(np.float64))
    x0 = np.clip(np.floor(px[..., 0] - 0.5).astype(int), 0, RES - 2)
    y0 = np.clip(np.floor(px[..., 1] - 0.5).astype(int), 0, RES - 2)
    taps = np.stack([depth[y0, x0], depth[y0, x0 + 1], depth[y0 + 1, x0], depth[y0 + 1, x0 + 1]])
    inside = (px[..., 0] >= 0) & (px[..., 0] <= RES) & (px[..., 1] >= 0) & (px[..., 1] <= RES) & (w > gi_cam.near)
    occluded = uv_pass["textured"] & inside & np.all((taps > 0) & (taps < 0.8 * w), axis=0)
    assert occluded.sum() >= 10, "the scene must hide some of the local view from the GI camera"
    assert not valid[occluded].any()
    # ...and visible when the texel it projects into holds its own point (within 1 %)
    nearest = depth[np.clip(px[..., 1].astype(int), 0, RES - 1), np.clip(px[..., 0].astype(int), 0, RES - 1)]
    visible = uv_pass["textured"] & inside & (np.abs(nearest - w) < 0.01 * w)
    assert visible.sum() >= 10 and valid[visible].mean() > 0.95, "pixels the GI camera sees stay valid"


# -- extreme inputs ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", METHODS)
def test_extreme_camera_black_map_zero_motion_is_finite(warp_renderer, method):
    c = cam(fov=170.0, near=1e-4, far=1e4)
    black = np.zeros((RES, RES, 3), np.float32)
    out, valid, _ = warp_both(method, warp_renderer, black, texel_depth(warp_renderer, c), c, c)
    assert np.all(np.isfinite(out)) and valid.any()
    di = warp_renderer.render_di(c, LIGHT)
    if method == "structure":  # with the fallback's base: the current DI
        warper = StructureAwareWarp(warp_renderer)
        warper.bind_texture(GITexture.build(c, black, texel_depth(warp_renderer, c)))
        out, _, _ = warper.resample(warp_renderer.render_uv(c), base=di)
    assert np.all(np.isfinite(out))
    metrics = all_metrics(tonemap(out), tonemap(di))
    assert all(math.isfinite(v) or v == math.inf for v in metrics.values())
    assert math.isfinite(metrics["ssim"])


def _smooth_map(res: int) -> np.ndarray:
    """A smooth GI map (1.5 periods across, per-channel phases), so that lookups can be checked in value."""
    v, u = np.mgrid[0:res, 0:res] / res
    return np.stack(
        [0.5 + 0.4 * np.sin(2 * np.pi * (1.5 * u + 0.3 * c)) * np.cos(2 * np.pi * (v + 0.2 * c)) for c in range(3)], -1
    ).astype(np.float32)


def _bilinear(image: np.ndarray, px: np.ndarray) -> np.ndarray:
    """``image`` looked up bilinearly at continuous pixel coordinates (col, row), centres at +0.5."""
    h, w = image.shape[:2]
    x, y = np.clip(px[..., 0] - 0.5, 0, w - 1), np.clip(px[..., 1] - 0.5, 0, h - 1)
    x0, y0 = np.minimum(np.floor(x).astype(int), w - 2), np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    return (
        image[y0, x0] * (1 - fx) * (1 - fy)
        + image[y0, x0 + 1] * fx * (1 - fy)
        + image[y0 + 1, x0] * (1 - fx) * fy
        + image[y0 + 1, x0 + 1] * fx * fy
    )


@pytest.mark.parametrize("local_fov", [1.0, 170.0])
@pytest.mark.parametrize("method", METHODS)
def test_extreme_local_fov_covers_and_fills(warp_renderer, method, local_fov):
    """A 90° GI map seen through a 1° zoom (one texel spans ~115 pixels) and a 170° wide angle (the map
    covers the middle 9 % of the width), from the GI camera's own position and direction.

    Every surface pixel whose centre ray meets the map gets it (a splat capped at a few pixels would
    leave a black frame here); elsewhere the fill stays within the map's range. Values: the
    structure-aware lookup is bilinear at the ray's texel coordinates; a pixel-level pixel holds a texel
    it covers (at 1°: the texel its centre ray meets, up to a one-pixel seam; at 170°: one of the ~11 x 11
    texels inside it)."""
    gi_cam, local = cam(fov=90.0), cam(fov=local_fov)
    image = _smooth_map(RES)
    out, valid, uv_pass = warp_both(method, warp_renderer, image, texel_depth(warp_renderer, gi_cam), gi_cam, local)
    surface = uv_pass["mask"]
    px, w = gi_cam.project_pixels(uv_pass["position"].astype(np.float64))
    inside = surface & (w > gi_cam.near) & np.all((px >= 0) & (px <= RES), axis=-1)
    assert inside.sum() >= (RES * RES // 2 if local_fov < 60 else 4)
    assert valid[inside].mean() >= 0.99
    if local_fov > 90:
        assert valid[surface & ~inside].mean() <= 0.05
    if method == "pixel":  # the hole filling (structure-aware's fallback is tested with its base elsewhere)
        filled = PointCloud(image, texel_depth(warp_renderer, gi_cam), gi_cam).splat(local, target_mask=surface)[0]
        assert (
            np.all(np.isfinite(filled))
            and image.min() - 1e-6 <= filled[surface].min()
            and filled[surface].max() <= image.max() + 1e-6
        )
    reference = _bilinear(image, px)
    error = np.abs(out - reference).max(axis=-1)[inside]
    if method == "structure":
        assert error.max() <= 1e-3
    elif local_fov < 60:
        assert error.mean() <= 0.03 and ssim(out, reference) >= 0.95  # a black frame: error ~0.5, SSIM ~0
    else:
        half = (
            0.5 * math.tan(math.radians(local_fov / 2)) / math.tan(math.radians(45.0)) + 1.0
        )  # texels per pixel / 2, + 1
        for (row, col), value in zip(np.argwhere(inside), out[inside]):
            cx, cy = px[row, col]
            window = image[
                max(0, int(cy - half)) : int(cy + half) + 1, max(0, int(cx - half)) : int(cx + half) + 1
            ].reshape(-1, 3)
            assert np.min(np.abs(window - value).max(axis=-1)) <= 1e-6, (row, col)


def test_pixel_level_zoom_shows_the_texel_each_ray_meets(warp_renderer):
    """At 1° every local pixel's centre ray meets one texel of a 90° map of random texels: the splat shows
    exactly that texel except on the one-pixel seams between the ~115-pixel squares."""
    gi_cam, local = cam(fov=90.0), cam(fov=1.0)
    image = np.random.default_rng(5).uniform(size=(RES, RES, 3)).astype(np.float32)
    out, valid, uv_pass = warp_both("pixel", warp_renderer, image, texel_depth(warp_renderer, gi_cam), gi_cam, local)
    px, _ = gi_cam.project_pixels(uv_pass["position"].astype(np.float64))
    met = image[px[..., 1].astype(int), px[..., 0].astype(int)]
    surface = uv_pass["mask"]
    assert valid[surface].all() and np.all(np.abs(out - met) <= 1e-6, axis=-1)[surface].mean() >= 0.95


def test_texture_precomputation_matches_direct_loops():
    """The vectorised slope slack and coarse fallback level equal their definitions, computed texel by
    texel and block by block (odd sizes, background holes)."""
    from gigan_local.warp import _coarse_level, depth_slack

    rng = np.random.default_rng(2)
    h, w, block = 13, 10, 4
    depth = np.where(rng.uniform(size=(h, w)) > 0.3, rng.uniform(1.0, 2.0, size=(h, w)), 0.0).astype(np.float32)

    def step(r: int, c: int, rr: int, cc: int) -> float | None:
        """Depth step to one neighbour: beyond the border it is the texel itself, on background none."""
        if not (0 <= rr < h and 0 <= cc < w):
            return 0.0
        return abs(float(depth[r, c] - depth[rr, cc])) if depth[rr, cc] > 0 else None

    slack = np.zeros((h, w), np.float32)
    for r, c in zip(*np.nonzero(depth)):
        for dr, dc in ((0, 1), (1, 0)):
            steps = [s for s in (step(r, c, r - dr, c - dc), step(r, c, r + dr, c + dc)) if s is not None]
            slack[r, c] += min(steps, default=0.0)
    np.testing.assert_allclose(depth_slack(depth), slack, rtol=1e-6)

    image = rng.uniform(size=(h, w, 2)).astype(np.float32)
    hit = depth > 0
    coarse, mean = _coarse_level(image, hit, block)
    for br in range(-(-h // block)):
        for bc in range(-(-w // block)):
            cells = (slice(br * block, (br + 1) * block), slice(bc * block, (bc + 1) * block))
            if hit[cells].any():  # blocks without hits are filled by push-pull
                np.testing.assert_allclose(coarse[br, bc], image[cells][hit[cells]].mean(axis=0), rtol=1e-5)
    np.testing.assert_allclose(mean, image[hit].mean(axis=0), rtol=1e-5)


def test_push_pull_keeps_valid_pixels_and_fills_holes():
    rng = np.random.default_rng(1)
    image = rng.uniform(size=(37, 21, 2)).astype(np.float32)  # odd sizes
    weight = (rng.uniform(size=(37, 21)) > 0.7).astype(np.float32)
    filled = push_pull(image, weight)
    assert np.all(np.isfinite(filled))
    np.testing.assert_array_equal(filled[weight == 1], image[weight == 1])
    assert filled.min() >= image.min() - 1e-6 and filled.max() <= image.max() + 1e-6  # convex combinations
    assert np.all(push_pull(image, np.zeros((37, 21))) == 0.0)


def test_bad_inputs_are_rejected(warp_renderer):
    c = cam()
    with pytest.raises(ValueError, match="NaN"):
        GITexture.build(c, np.full((RES, RES, 3), np.nan, np.float32), np.ones((RES, RES)))
    with pytest.raises(ValueError, match="GI map"):
        GITexture.build(c, np.zeros((RES + 1, RES, 3)), np.ones((RES + 1, RES)))
    with pytest.raises(RuntimeError, match="bind"):
        StructureAwareWarp(warp_renderer).resample(warp_renderer.render_uv(c))
    with pytest.raises(RuntimeError, match="bind"):
        PixelWarp().warp(c, np.zeros((RES, RES, 3), np.float32), {"mask": np.ones((RES, RES), bool)})
    with pytest.raises(ValueError, match="NaN"):
        PointCloud(np.zeros((RES, RES, 3)), np.full((RES, RES), np.inf), c)
    warper = StructureAwareWarp(warp_renderer)
    warper.bind_texture(GITexture.build(c, np.ones((RES, RES, 3), np.float32), texel_depth(warp_renderer, c)))
    with pytest.raises(ValueError, match="NaN"):
        warper.resample(warp_renderer.render_uv(c), base=np.full((RES, RES, 3), np.nan, np.float32))
    with pytest.raises(ValueError, match="layer"):
        PixelWarp(layer="di")
