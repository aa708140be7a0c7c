"""The pixel-level warp's GL backend (baseline_cloudbaking.gl_warp) against the numpy warp on llvmpipe.

Bounds: the GL bind draws the numpy point cloud on the GPU, in float32 (numpy unprojects in float64 and rounds):
its points are numpy's to float32 rounding (a few ulps). On the same points, the splat keeps, per pixel, the
nearest point and among equal depths the smallest index (the numpy warp's packed key), and the push-pull passes
repeat gicore.fill.push_pull's sums and divisions in its order. One value differs: a point's depth in the target
camera, a 4x4 product that numpy's matmul (BLAS) and the shader may round to neighbouring float32 values. Where
two points on one surface cover a pixel at depths one ulp apart, the other one can win: that pixel takes a
neighbouring texel's colour (and the hole filling near it moves a little). So at most DIFFER of the pixels differ
by more than float32 rounding, by at most the map's contrast between texels two apart (the footprints here are
<= 2 texels, but for the zoomed view, where each point covers several pixels, any point nearby); the valid masks
are equal. The GPU's points, a few ulps off the rounded exact ones, lie within one ulp of each other's depth
more often than exact ones do: measured on lung_plane (GI frames 0, 100, 200, ten views each) at 256², at most
0.42 % of the pixels of a view on the same points (0.22 % when both splatted numpy's points), and at most 1.1 %
end to end (each warp on its own points, DIFFER_OWN_POINTS), the median view 0; at 48² here 0.52 % and 1.1 %,
mean abs <= 3.2e-4, max abs 0.2 against a contrast of 1.47. ``cloudbaking-client --warp-backend gl`` runs
against the module server of tests/baseline_cloudbaking/test_client.py.

Skipped, with the reason, when no GL context opens.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from baseline_cloudbaking.gl_warp import GLPixelWarp
from baseline_cloudbaking.warp import PixelWarp, PointCloud
from gicore.gi_map import GIMap
from gicore.gl import gl_available
from gicore.gl.fill import pyramid_sizes
from gicore.tonemap import linear_of_display, tonemap
from tests.helpers.gl_warps import contrast, differences, loop_frames, lung_scene

OK, WHY = gl_available()
if not OK:
    pytest.skip(f"no OpenGL context: {WHY}", allow_module_level=True)

#: Most pixels that differ by more than float32 rounding, and the largest mean |gl - numpy|, on the same points
#: and end to end (module docstring).
DIFFER, MEAN_ABS = 0.0075, 3e-4
DIFFER_OWN_POINTS, MEAN_ABS_OWN_POINTS = 0.02, 6e-4


@pytest.fixture(scope="module")
def lung():
    return lung_scene()


def test_pyramid_sizes_halve_rounding_up():
    assert pyramid_sizes(48, 48) == [(48, 48), (24, 24), (12, 12), (6, 6), (3, 3), (2, 2), (1, 1)]
    assert pyramid_sizes(5, 1) == [(5, 1), (3, 1), (2, 1), (1, 1)] and pyramid_sizes(1, 1) == [(1, 1)]


def on_points(host: PixelWarp, gi: GIMap, drawn: np.ndarray) -> PixelWarp:
    """``host``, bound to ``gi``, with its point cloud's points replaced by the GL bind's ``drawn`` ones."""
    host.bind(gi)
    hit = gi.depth.ravel() > 0
    host.cloud.points[:3], host.cloud.src_depth_over_focal = drawn[hit, :3].T, drawn[hit, 3]
    return host


def test_gl_bind_draws_the_numpy_point_cloud_to_float32_rounding(lung):
    gi = lung[3]
    shader = GLPixelWarp(lung[0])
    shader.bind(gi)
    drawn, cloud, hit = shader.drawn_points(), PointCloud(gi.radiance, gi.depth, gi.camera), gi.depth.ravel() > 0
    assert np.all(drawn[~hit] == 0.0)  # no point off the surfaces
    np.testing.assert_allclose(drawn[hit, :3], cloud.points[:3].T, rtol=0, atol=4e-6)
    np.testing.assert_allclose(drawn[hit, 3], cloud.src_depth_over_focal, rtol=1e-5)


@pytest.mark.parametrize("points", ["same", "own"])
@pytest.mark.parametrize("layer", ["radiance", "indirect"])
def test_gl_pixel_warp_matches_numpy(lung, layer, points):
    gl, cams, light, gi = lung
    shader = GLPixelWarp(gl, layer)
    shader.bind(gi)
    host = on_points(PixelWarp(layer), gi, shader.drawn_points()) if points == "same" else PixelWarp(layer)
    if points == "own":
        host.bind(gi)
    near, far = contrast(gi.layer(layer)), contrast(gi.layer(layer), reach=8)
    zoomed = cams[10].with_fov(12.0)  # one map texel over several pixels: footprints k > 2
    for camera in (gi.camera, cams[0], cams[5], cams[20], cams[40], zoomed):
        di, passes = gl.render_di_raster(camera, light, "mask")
        expected = host.warp(camera, di, passes)[:2]
        d = differences(shader.warped(camera, light), expected)
        print(f"{layer} {points} points, fov {camera.fov} {camera.origin}: {d}")
        differ, mean_abs = (DIFFER, MEAN_ABS) if points == "same" else (DIFFER_OWN_POINTS, MEAN_ABS_OWN_POINTS)
        assert d["differ"] <= differ and d["mean_abs"] <= mean_abs and d["valid_differs"] == 0.0
        assert d["max_abs"] <= (far if camera is zoomed else near)
        assert expected[1].mean() < 1.0 or camera is gi.camera  # holes to fill away from the map's own view


def test_a_display_map_binds_as_its_linear_decode(lung):
    """An 8-bit codec's display values decoded on the GPU by the host decode's table: the same frame, bit for bit,
    as the same map bound as the host's linear decode of them."""
    gl, cams, light, gi = lung
    display = np.rint(tonemap(gi.radiance) * 255.0).astype(np.uint8)
    as_display = replace(gi, linear=None, display=display)
    as_linear = replace(gi, linear=linear_of_display(display), display=None)
    frames = []
    for bound in (as_display, as_linear):
        shader = GLPixelWarp(gl)
        shader.bind(bound)
        frames.append(shader.warped(cams[5], light))
    assert np.array_equal(frames[0][0], frames[1][0]) and np.array_equal(frames[0][1], frames[1][1])
    assert frames[0][1].mean() > 0.3  # the map reaches that view


@pytest.mark.parametrize("composition", ["blend", "residual"])
def test_client_loop_frames_on_gl_equal_numpy_frames(lung, composition):
    gl, gi = lung[0], lung[3]
    layer = "radiance" if composition == "blend" else "indirect"
    frames = {"gl": loop_frames(lung, GLPixelWarp(gl, layer), composition)}
    frames["numpy"] = loop_frames(lung, PixelWarp(layer), composition)
    for a, b in zip(frames["gl"], frames["numpy"]):
        d = differences((a.image, a.row["valid_frac"]), (b.image, b.row["valid_frac"]))  # each on its own points
        assert d["differ"] <= DIFFER_OWN_POINTS and d["mean_abs"] <= MEAN_ABS_OWN_POINTS and d["valid_differs"] == 0.0
        assert d["max_abs"] <= contrast(gi.layer(layer))
    assert {"di_ms", "splat_ms", "fill_ms", "compose_ms"} <= set(frames["gl"][0].row)
    assert "project_ms" not in frames["gl"][0].row and all(r.row["splat_ms"] > 0 for r in frames["gl"])
