"""The pixel-level warp (:mod:`baseline_cloudbaking.warp`) as GL passes on the GL renderer's own textures: the
bound map's point cloud is splatted into the frame and its holes are filled by a push-pull pyramid, with the
frame's surface mask (the DI target's alpha) read where the renderer drew it (docs/architecture.md,
Pixel-level warping).

Per map, :meth:`GLPixelWarp.bind` builds the numpy warp's :class:`~baseline_cloudbaking.warp.PointCloud` and
uploads its points (one instance each) and colours as textures: the map arrives decoded in host memory either
way (the Web3D page unprojects its maps in a shader into the same texture layout). Per frame, with the sources
of :mod:`gicore.gl.sources` that the page draws too:

1. **splat**: each point is projected as the numpy warp projects it and drawn as its ``k x k`` square, a quad
   whose corners lie on pixel edges (so every covered pixel centre is half a pixel inside it), clipped to the
   frame; two passes with ``MIN`` blending on float32 targets keep, per pixel, the nearest point's depth and
   then the smallest index among the points at that depth: the numpy warp's packed key (depth, then index),
   exactly, where a depth equals the numpy warp's to the bit.
2. **fill**: the winners' colours where the surface mask is set, then :func:`gicore.fill.push_pull`'s pull
   (2x2 weight-normalised sums, zero-padded) and push (nearest upsampling) passes in its order of operations
   (:mod:`gicore.gl.fill`), the background set to 0.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from baseline_cloudbaking.warp import FOOTPRINT_EPS, MAX_FOOTPRINT, PointCloud
from gicore.camera import Camera
from gicore.gi_map import LAYERS, GIMap, Timings
from gicore.gl.fill import PushPull
from gicore.gl.frame import ShaderWarp
from gicore.gl.passes import Pass, Target, upload
from gicore.gl.shaders import mat_bytes
from gicore.gl.sources import glsl
from gicore.timing import Stopwatch

if TYPE_CHECKING:
    from gicore.gl.renderer import GLRenderer

#: Points a map may have: their indices are float32 values of a MIN-blended target, exact below 2^24.
MAX_POINTS = 1 << 24
#: The empty pixel of the splat targets (larger than any depth or index).
EMPTY = 3.0e38

#: The splat's and resolve's shaders (``pixel_NAME``) and the constants they share with the numpy warp.
DEFINES = {"MAX_FOOTPRINT": MAX_FOOTPRINT, "FOOTPRINT_EPS": FOOTPRINT_EPS, "EMPTY": EMPTY}


class GLPixelWarp(ShaderWarp):
    """Pixel-level warping in GL passes on ``renderer`` (a :class:`gicore.gl.GLRenderer`), the cloud-baking
    client's warp with ``--warp-backend gl``: :meth:`bind` a map's point cloud once, then
    :meth:`~gicore.gl.frame.ShaderWarp.frame` composes each frame (module docstring)."""

    name = "pixel"
    raster = "mask"
    stages = ("bind", "splat", "fill")

    def __init__(self, renderer: GLRenderer, layer: str = "radiance"):
        if layer not in LAYERS.values():
            raise ValueError(f"layer must be one of {tuple(LAYERS.values())}, got {layer!r}")
        super().__init__(renderer)
        self.layer = layer
        ctx, n = self.ctx, renderer.resolution
        self._splat = Pass(ctx, glsl("pixel_splat.frag"), glsl("pixel_splat.vert", DEFINES))
        self._resolve = Pass(ctx, glsl("pixel_resolve.frag", DEFINES))
        self._nearest, self._index = Target.make(ctx, n, n, 1), Target.make(ctx, n, n, 1)
        self._fill = PushPull(ctx, n, n)
        self.cloud: PointCloud | None = None
        self._points: Any = None
        self._colours: Any = None

    def bind(self, gi: GIMap) -> Timings:
        """Per GI map: the numpy warp's point cloud, its points and colours uploaded (point i at texel
        (i % width, i / width), as the splat and the resolve read them)."""
        sw = Stopwatch()
        cloud = PointCloud(gi.layer(self.layer), gi.depth, gi.camera)
        n_points = cloud.points.shape[1]
        if cloud.channels != 3 or n_points >= MAX_POINTS:
            raise ValueError(f"the GL warp takes a 3-channel map of fewer than {MAX_POINTS} points")
        width = gi.camera.width
        rows = np.zeros((-(-max(n_points, 1) // width) * width, 7), np.float32)  # a texture is never empty
        rows[:n_points, :3], rows[:n_points, 3] = cloud.points[:3].T, cloud.src_depth_over_focal
        rows[:n_points, 4:] = cloud.colours
        self._points = upload(self.ctx, rows[:, :4].reshape(-1, width, 4))
        self._colours = upload(self.ctx, rows[:, 4:].reshape(-1, width, 3))
        self.cloud = cloud
        self.ctx.finish()
        sw.lap("bind")
        return sw.ms

    def draw(self, camera: Camera, textures: dict[str, Any], sw: Stopwatch) -> Target:
        if self.cloud is None:
            raise RuntimeError("no GI map is bound; call bind() first")
        self._draw_splat(camera)
        inputs = {"u_index": self._index.texture, "u_colours": self._colours, "u_mask": textures["di"]}
        self._resolve.draw(self._fill.level0, inputs)
        self.lap(sw, "splat")
        filled = self._fill.run(mask=textures["di"])
        self.lap(sw, "fill")
        return filled

    def _draw_splat(self, camera: Camera) -> None:
        """The nearest depth per pixel, then the smallest index at that depth (module docstring, step 1)."""
        ctx = self.ctx
        f32 = np.float32  # each constant as numpy rounds a python float against a float32 array
        uniforms = {
            "u_vp": mat_bytes(camera.view_proj()),
            "u_near": float(f32(camera.near)),
            "u_focal_px": float(f32(camera.proj()[0, 0] * camera.width / 2.0)),
            "u_size": (float(camera.width), float(camera.height)),
        }
        n_points = self.cloud.points.shape[1]
        ctx.enable(ctx.BLEND)
        ctx.blend_equation = ctx.MIN
        for target, index in ((self._nearest, False), (self._index, True)):
            target.fbo.clear(EMPTY, EMPTY, EMPTY, EMPTY)
            if n_points:
                inputs = {"u_points": self._points} | ({"u_nearest": self._nearest.texture} if index else {})
                self._splat.draw(target, inputs, uniforms | {"u_index": index}, self._splat.vao,
                                 mode=ctx.TRIANGLE_STRIP, vertices=4, instances=n_points)  # fmt: skip
        ctx.blend_equation = ctx.FUNC_ADD
        ctx.disable(ctx.BLEND)
