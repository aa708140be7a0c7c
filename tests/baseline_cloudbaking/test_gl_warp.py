"""The pixel-level warp's GL backend (baseline_cloudbaking.gl_warp) against the numpy warp on llvmpipe.

Bounds: the splat keeps, per pixel, the nearest point and among equal depths the smallest index (the numpy
warp's packed key), from the numpy point cloud's float32 points, and the push-pull passes repeat
gicore.fill.push_pull's sums and divisions in its order. One value differs: a point's depth in the target
camera, a 4x4 product that numpy's matmul (BLAS) and the shader may round to neighbouring float32 values. Where
two points on one surface cover a pixel at depths one ulp apart, the other one can win: that pixel takes a
neighbouring texel's colour (and the hole filling near it moves a little). So at most DIFFER of the pixels differ
by more than float32 rounding, by at most the map's contrast between texels two apart (the footprints here are
<= 2 texels, but for the zoomed view, where each point covers several pixels, any point nearby); the valid masks
are equal. Measured on lung_plane (GI frames 0, 100, 200, ten views each): 0.09 % of pixels at 48², <= 0.22 %
at 256², mean abs <= 1.3e-5, max abs 0.19 against a contrast of 1.47. ``cloudbaking-client --warp-backend gl`` runs
against the module server of tests/baseline_cloudbaking/test_client.py.

Skipped, with the reason, when no GL context opens.
"""

from __future__ import annotations

import pytest

from baseline_cloudbaking.gl_warp import GLPixelWarp
from baseline_cloudbaking.warp import PixelWarp
from gicore.gl import gl_available
from gicore.gl.fill import pyramid_sizes
from tests.helpers.gl_warps import contrast, differences, loop_frames, lung_scene

OK, WHY = gl_available()
if not OK:
    pytest.skip(f"no OpenGL context: {WHY}", allow_module_level=True)

#: Most pixels that differ by more than float32 rounding, and the largest mean |gl - numpy| (module docstring).
DIFFER, MEAN_ABS = 0.005, 1e-4


@pytest.fixture(scope="module")
def lung():
    return lung_scene()


def test_pyramid_sizes_halve_rounding_up():
    assert pyramid_sizes(48, 48) == [(48, 48), (24, 24), (12, 12), (6, 6), (3, 3), (2, 2), (1, 1)]
    assert pyramid_sizes(5, 1) == [(5, 1), (3, 1), (2, 1), (1, 1)] and pyramid_sizes(1, 1) == [(1, 1)]


@pytest.mark.parametrize("layer", ["radiance", "indirect"])
def test_gl_pixel_warp_matches_numpy(lung, layer):
    gl, cams, light, gi = lung
    shader, host = GLPixelWarp(gl, layer), PixelWarp(layer)
    shader.bind(gi)
    host.bind(gi)
    near, far = contrast(gi.layer(layer)), contrast(gi.layer(layer), reach=8)
    zoomed = cams[10].with_fov(12.0)  # one map texel over several pixels: footprints k > 2
    for camera in (gi.camera, cams[0], cams[5], cams[20], cams[40], zoomed):
        di, passes = gl.render_di_raster(camera, light, "mask")
        expected = host.warp(camera, di, passes)[:2]
        d = differences(shader.warped(camera, light), expected)
        print(f"{layer} fov {camera.fov} {camera.origin}: {d}")
        assert d["differ"] <= DIFFER and d["mean_abs"] <= MEAN_ABS and d["valid_differs"] == 0.0
        assert d["max_abs"] <= (far if camera is zoomed else near)
        assert expected[1].mean() < 1.0 or camera is gi.camera  # holes to fill away from the map's own view


@pytest.mark.parametrize("composition", ["blend", "residual"])
def test_client_loop_frames_on_gl_equal_numpy_frames(lung, composition):
    gl, gi = lung[0], lung[3]
    layer = "radiance" if composition == "blend" else "indirect"
    frames = {"gl": loop_frames(lung, GLPixelWarp(gl, layer), composition)}
    frames["numpy"] = loop_frames(lung, PixelWarp(layer), composition)
    for a, b in zip(frames["gl"], frames["numpy"]):
        d = differences((a.image, a.row["valid_frac"]), (b.image, b.row["valid_frac"]))
        assert d["differ"] <= DIFFER and d["mean_abs"] <= MEAN_ABS and d["valid_differs"] == 0.0
        assert d["max_abs"] <= contrast(gi.layer(layer))
    assert {"di_ms", "splat_ms", "fill_ms", "compose_ms"} <= set(frames["gl"][0].row)
    assert "project_ms" not in frames["gl"][0].row and all(r.row["splat_ms"] > 0 for r in frames["gl"])
