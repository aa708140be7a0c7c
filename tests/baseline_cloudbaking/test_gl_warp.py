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
at 256², mean abs <= 1.3e-5, max abs 0.19 against a contrast of 1.47.

Skipped, with the reason, when no GL context opens.
"""

from __future__ import annotations

import csv
import json
import subprocess
from pathlib import Path

import pytest

from baseline_cloudbaking.gl_warp import GLPixelWarp, pyramid_sizes
from baseline_cloudbaking.warp import PixelWarp
from gicore.gl import gl_available
from tests.helpers.cloud import BIN, SPP, server_process, write_scenes
from tests.helpers.cloud import RES as CLOUD_RES
from tests.helpers.gl_warps import contrast, differences, loop_frames, lung_scene
from tests.helpers.guards import HANG_GUARD_S

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


def test_cloud_client_with_the_gl_warp_backend(tmp_path: Path) -> None:
    """``cloudbaking-client --warp-backend gl``: frames warped and composed in GL, the GL warp's stages in the
    frame columns and in each request's warp time, and the summary naming the backend that ran."""
    scenes = write_scenes(tmp_path / "scenes")
    with server_process(tmp_path / "store", scenes, "--max-spp", "16") as server:
        argv = [str(BIN / "cloudbaking-client"), "--server", server, "--scene", str(scenes / "ball_moving.json")]
        argv += ["--frames", "4", "--resolution", str(CLOUD_RES), "-k", "2", "--spp", str(SPP), "--warp-backend", "gl"]
        proc = subprocess.run(
            [*argv, "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=HANG_GUARD_S
        )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["warp_backend"] == "gl" and summary["config"]["warp_backend"] == "gl"
    with (tmp_path / "out" / "frames.csv").open() as fh:
        frames = list(csv.DictReader(fh))
    assert "project_ms" not in frames[0] and float(frames[0]["bind_ms"]) > 0
    assert all(float(r["splat_ms"]) > 0 and float(r["fill_ms"]) > 0 and float(r["valid_frac"]) > 0.5 for r in frames)
    with (tmp_path / "out" / "requests.csv").open() as fh:
        shown = [r for r in csv.DictReader(fh) if r["total_ms"]]
    assert shown and all(float(r["warp_ms"]) > 0 for r in shown)
