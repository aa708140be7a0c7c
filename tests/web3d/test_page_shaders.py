"""The page's own shader sources (web3d/glsl) compiled as GLSL 330 on the desktop against the Python they port:
a cloud map's point cloud (``cloud_map.frag``) is baseline_cloudbaking.warp.PointCloud's points and footprints up
to float32 rounding (the shader unprojects in float32, numpy in float64: 1e-6 measured), and its colours are the
codec's decoding of the 8-bit values. Skipped, with the reason, when no GL context opens."""

from __future__ import annotations

import numpy as np
import pytest

from baseline_cloudbaking.warp import PointCloud
from gicore.gl import gl_available
from gicore.gl.shaders import mat_bytes
from gicore.gl.sources import glsl
from gicore.tonemap import inverse_tonemap
from tests.helpers.gl_warps import lung_scene
from web3d.shaders import PAGE_GLSL

OK, WHY = gl_available()
if not OK:
    pytest.skip(f"no OpenGL context: {WHY}", allow_module_level=True)


def test_cloud_map_is_the_numpy_point_cloud_and_the_codecs_colours() -> None:
    from gicore.gl.passes import Pass, Target, upload

    gl, _, _, gi = lung_scene()
    ctx, camera = gl.ctx, gi.camera
    h, w = gi.depth.shape
    q = np.random.default_rng(0).integers(0, 256, (h, w, 3)).astype(np.float32)
    points, colours = Target.make(ctx, w, h, 4), Target.make(ctx, w, h, 4)
    both = Target(points.texture, ctx.framebuffer([points.texture, colours.texture]), 4)
    uniforms = {"u_inv_view": mat_bytes(np.linalg.inv(camera.view())), "u_focal": tuple(camera.proj()[[0, 1], [0, 1]])}
    textures = {"u_depth": upload(ctx, gi.depth), "u_gi": upload(ctx, q / 255.0)}
    Pass(ctx, glsl("cloud_map.frag", folder=PAGE_GLSL)).draw(both, textures, uniforms)
    drawn, decoded = points.read().reshape(-1, 4), colours.read()[..., :3]
    cloud = PointCloud(q, gi.depth, camera)
    hit = gi.depth.ravel() > 0
    assert np.all(drawn[~hit] == 0.0)  # no point off the surfaces
    np.testing.assert_allclose(drawn[hit, :3], cloud.points[:3].T, rtol=0, atol=4e-6)
    np.testing.assert_allclose(drawn[hit, 3], cloud.src_depth_over_focal, rtol=1e-5)
    np.testing.assert_allclose(decoded, inverse_tonemap(np.minimum(q / 255.0, 254.5 / 255.0)), rtol=1e-4)
