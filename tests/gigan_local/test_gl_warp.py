"""The structure-aware warp's GL backend (gigan_local.gl_warp) and the composition's (gicore.gl.blend) against
their numpy versions on llvmpipe, and `--warp-backend`'s choice.

Bounds: the shaders compute the numpy warp's float32 operations in its order (the same taps, the weights rounded
to 1/256 as numpy rounds them, the same depth planes drawn and coarse level uploaded), and on llvmpipe the outputs are
identical (max abs 0 measured on lung_plane at 48² and 256²). The bounds leave room only for a compiler that
reassociates float32 arithmetic (a fused multiply-add, a division as a reciprocal): a few ulps of values <= 1
(< 1e-6), far below MAX_ABS; a different tap, weight or fallback would exceed it. Eq. 1's blend is two products
and a sum: equal up to one float32 rounding of each (rtol 2^-22).

Skipped, with the reason, when no GL context opens.
"""

from __future__ import annotations

import numpy as np
import pytest

from gicore.gl import gl_available
from gicore.run_config import PathRunConfig
from gigan_local.gl_warp import GLStructureWarp
from gigan_local.warp import StructureAwareWarp
from tests.helpers.gl_warps import RES, differences, loop_frames, lung_scene

OK, WHY = gl_available()
if not OK:
    pytest.skip(f"no OpenGL context: {WHY}", allow_module_level=True)

#: Largest |gl - numpy| of a warped or composed pixel, and of their mean (see the module docstring).
MAX_ABS, MEAN_ABS = 1e-5, 1e-6


@pytest.fixture(scope="module")
def lung():
    return lung_scene()


@pytest.mark.parametrize("layer", ["radiance", "indirect"])
def test_gl_structure_warp_matches_numpy(lung, layer):
    gl, cams, light, gi = lung
    shader, host = GLStructureWarp(gl, layer), StructureAwareWarp(gl, layer)
    shader.bind(gi)
    host.bind(gi)
    for camera in (gi.camera, cams[5], cams[20], cams[40]):  # the map's own view (identity), then farther
        di, passes = gl.render_di_raster(camera, light, "uv")
        expected = host.resample(passes, base=di if layer == "radiance" else None)[:2]
        expected = (expected[0], expected[1] | ~passes["mask"])
        d = differences(shader.warped(camera, light), expected)
        print(f"{layer} {camera.origin}: {d}")
        assert d["max_abs"] <= MAX_ABS and d["mean_abs"] <= MEAN_ABS and d["valid_differs"] == 0.0
    assert 0.0 < expected[1].mean() < 1.0  # the farthest view has invalid pixels: the fallback is compared too


def test_gl_bind_draws_the_numpy_depth_planes_to_the_bit(lung):
    """The slack pass computes depth_slack's float32 operations texel by texel: the planes it draws from the map's
    depth are GITexture's (borders, background holes and ±inf included), and a NaN map is refused before any
    upload."""
    from dataclasses import replace

    from gigan_local.warp import GITexture

    gl, _, _, gi = lung
    depth = gi.depth.copy()
    depth[::7, ::5] = 0.0  # background texels inside the surface: slopes to them are edges
    gi = replace(gi, depth=depth)
    shader = GLStructureWarp(gl, "radiance")
    shader.bind(gi)
    drawn = shader._planes.read()
    texture = GITexture.build(gi.camera, gi.layer("radiance"), gi.depth, gi.indirect)
    expected = texture.planes[:2].reshape(2, *depth.shape).transpose(1, 2, 0)
    assert np.array_equal(drawn, expected) and np.isinf(drawn).any()
    with pytest.raises(ValueError, match="NaN or Inf"):
        shader.bind(replace(gi, depth=np.full_like(depth, np.nan)))


@pytest.mark.parametrize("composition", ["blend", "residual"])
def test_client_loop_frames_on_gl_equal_numpy_frames(lung, composition):
    layer = "radiance" if composition == "blend" else "indirect"
    gl = lung[0]
    frames = {"gl": loop_frames(lung, GLStructureWarp(gl, layer), composition)}
    frames["numpy"] = loop_frames(lung, StructureAwareWarp(gl, layer), composition)
    for a, b in zip(frames["gl"], frames["numpy"]):
        assert np.abs(a.image - b.image).max() <= MAX_ABS and a.row["valid_frac"] == b.row["valid_frac"]
    assert {"di_ms", "warp_ms", "compose_ms"} <= set(frames["gl"][0].row) and "project_ms" not in frames["gl"][0].row
    assert all(r.row["warp_ms"] > 0 for r in frames["gl"])


def test_gl_compose_equals_numpy_up_to_float32_rounding(lung):
    from gicore.blend import blend, residual
    from gicore.gl.blend import GLCompose
    from gicore.gl.passes import upload

    gl = lung[0]
    rng = np.random.default_rng(0)
    di, warped = rng.random((2, RES, RES, 3), dtype=np.float32) * 4.0
    valid = rng.random((RES, RES)) < 0.7
    textures = upload(gl.ctx, di), upload(gl.ctx, np.dstack([warped, valid]))
    compose = GLCompose(gl.ctx, RES, RES)
    for composition, tau in (("blend", 0.0), ("blend", 0.3), ("blend", 1.0), ("residual", 0.0)):
        compose.draw(*textures, composition, tau)
        image, mask = compose.read()
        expected = blend(di, warped, tau) if composition == "blend" else residual(di, warped, np.zeros_like(di))
        np.testing.assert_allclose(image, expected, rtol=2.0**-22, atol=0.0)
        assert np.array_equal(mask, valid)


def test_warp_backend_choice(monkeypatch, capsys):
    import gicore.gl.frame as frame

    assert frame.warp_backend("auto", "gl") == "numpy"  # llvmpipe here: numpy is the CPU default
    assert frame.warp_backend("gl", "gl") == "gl" and frame.warp_backend("numpy", "gl") == "numpy"
    assert frame.warp_backend("auto", "mitsuba") == "numpy" and capsys.readouterr().err == ""
    assert frame.warp_backend("gl", "mitsuba", warn=True) == "numpy"  # gl asked, no GL context opened
    assert capsys.readouterr().err == "warning: warp backend gl needs the GL renderer, using numpy\n"
    monkeypatch.setattr(frame, "gl_info", lambda: {"GL_RENDERER": "NVIDIA H100 80GB HBM3/PCIe/SSE2"})
    assert frame.warp_backend("auto", "gl") == "gl"
    with pytest.raises(ValueError, match="warp backend must be one of"):
        frame.warp_backend("cuda", "gl")
    with pytest.raises(ValueError, match="--warp-backend gl runs on the GL renderer's textures: pass --renderer gl"):
        PathRunConfig(renderer="mitsuba", warp_backend="gl")


def test_gigan_client_with_the_gl_warp_backend(make_spec, tmp_path):
    """``gigan-client --warp-backend gl``: frames warped and composed in GL, the GL warp's stage in the frame
    columns, and the summary naming the backend that ran (auto picks numpy on llvmpipe)."""
    import json

    from gigan_local.client import ClientConfig, run

    spec_file = tmp_path / "scene.json"
    spec_file.write_text(json.dumps(make_spec(with_box=True).to_dict()))
    fields = dict(scene=str(spec_file), frames=4, resolution=32, every=2, orbit_frames=40, spp=2, denoise=False)
    for backend, ran in (("gl", "gl"), ("auto", "numpy")):
        summary = run(ClientConfig(**fields, warp_backend=backend), tmp_path / backend)
        assert summary["renderer"] == "gl" and summary["warp_backend"] == ran
        stage = {"gl": "warp_ms", "numpy": "project_ms"}[ran]
        assert summary["median"][stage] > 0 and summary["mean_valid_frac"] > 0.5
