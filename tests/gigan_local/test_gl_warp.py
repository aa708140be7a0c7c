"""The structure-aware warp's GL backend (gigan_local.gl_warp) and the composition's (gicore.gl.blend) against
their numpy versions on llvmpipe, and `--warp-backend`'s choice.

Bounds: the shaders compute the numpy warp's float32 operations in its order (the same taps, the weights rounded
to 1/256 as numpy rounds them, the same depth planes drawn; the coarse level's block sums and mean are summed in
another order, a few ulps on fallback pixels), and on llvmpipe the outputs are equal up to that (max abs 6e-8
measured on lung_plane at 48²). A GPU's compiler may reassociate float32
arithmetic (a fused multiply-add, a division as a reciprocal): a few ulps, and where that moves a bilinear weight
across one of its 1/256 rounding steps, the pixel changes by 1/256 of the step between two neighbouring texels
(measured on an H100: 1.3e-5 on values near 0.37, in a few pixels). So a pixel may differ by MAX_ABS plus
2/256 of the map's largest neighbour step (one step in x, one in y), and at most MAX_SHARE of the pixels by
more than MAX_ABS; a wrong tap, weight or fallback exceeds both. Eq. 1's blend is two products and a sum: equal
up to one float32 rounding of each (rtol 2^-22).

Skipped, with the reason, when no GL context opens.
"""

from __future__ import annotations

import numpy as np
import pytest

from gicore.gl import gl_available
from gicore.run_config import PathRunConfig
from gigan_local.gl_warp import GLStructureWarp
from gigan_local.warp import SUBTEXEL, StructureAwareWarp
from tests.helpers.gl_warps import RES, ULPS, contrast, differences, loop_frames, lung_scene

OK, WHY = gl_available()
if not OK:
    pytest.skip(f"no OpenGL context: {WHY}", allow_module_level=True)

#: |gl - numpy| of a warped or composed pixel from float32 rounding alone, and the share of pixels that may differ
#: by more, by a weight's rounding step (see the module docstring).
MAX_ABS, MAX_SHARE = ULPS, 0.01


def rounding_step_bound(gi) -> float:
    """The most a pixel of a map's warp may move when rounding moves its weights across 1/SUBTEXEL steps."""
    return MAX_ABS + 2.0 * contrast(gi.radiance, reach=1) / SUBTEXEL


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
        assert d["max_abs"] <= rounding_step_bound(gi) and d["differ"] <= MAX_SHARE and d["valid_differs"] == 0.0
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
        diff = np.abs(a.image - b.image).max(axis=-1)
        assert diff.max() <= rounding_step_bound(lung[3]) and np.mean(diff > MAX_ABS) <= MAX_SHARE
        assert a.row["valid_frac"] == b.row["valid_frac"]
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

    monkeypatch.setattr(frame, "gl_info", lambda: {"GL_RENDERER": "llvmpipe (LLVM 15.0.6, 256 bits)"})
    assert frame.warp_backend("auto", "gl") == "numpy"  # a CPU rasteriser: numpy is the default
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
    columns, and the summary naming the backend that ran (auto: numpy on a CPU rasteriser, gl on a GPU)."""
    import json

    from gigan_local.client import ClientConfig, run

    spec_file = tmp_path / "scene.json"
    spec_file.write_text(json.dumps(make_spec(with_box=True).to_dict()))
    fields = dict(scene=str(spec_file), frames=4, resolution=32, every=2, orbit_frames=40, spp=2, denoise=False)
    from gicore.gl.frame import warp_backend

    for backend, ran in (("gl", "gl"), ("auto", warp_backend("auto", "gl"))):
        summary = run(ClientConfig(**fields, warp_backend=backend), tmp_path / backend)
        assert summary["renderer"] == "gl" and summary["warp_backend"] == ran
        stage = {"gl": "warp_ms", "numpy": "project_ms"}[ran]
        assert summary["median"][stage] > 0 and summary["mean_valid_frac"] > 0.5
