"""The pixel-level warp (:mod:`baseline_cloudbaking.warp`) as GL passes on the GL renderer's own textures: the
bound map's point cloud is splatted into the frame and its holes are filled by a push-pull pyramid, with the
frame's surface mask (the DI target's alpha) read where the renderer drew it (docs/architecture.md,
Pixel-level warping).

Per map, :meth:`GLPixelWarp.bind` uploads the map and its depth and draws the numpy warp's
:class:`~baseline_cloudbaking.warp.PointCloud` on the GPU (``pixel_cloud.frag``, as the Web3D page does): a
point and a colour per texel, background texels pointless. A map that arrived as an 8-bit codec's display values
(:attr:`gicore.gi_map.GIMap.display`) is uploaded as bytes and decoded there by the host decode's own table, so
neither the decode nor the bind turns it into linear radiance on the host. Per frame, with the sources of
:mod:`gicore.gl.sources` that the page draws too:

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

from baseline_cloudbaking.warp import FOOTPRINT_EPS, MAX_FOOTPRINT
from gicore.camera import Camera
from gicore.gi_map import LAYERS, GIMap, Timings
from gicore.gl.fill import PushPull
from gicore.gl.frame import ShaderWarp
from gicore.gl.passes import Pass, Target, upload
from gicore.gl.shaders import mat_bytes
from gicore.gl.sources import glsl
from gicore.timing import Stopwatch
from gicore.tonemap import LINEAR_OF_U8

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
    client's warp with ``--warp-backend gl``: :meth:`bind` a map's point cloud once (drawn on the GPU), then
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
        self._cloud = {shown: Pass(ctx, glsl("pixel_cloud.frag", {"DISPLAY": None} if shown else {}))
                       for shown in (False, True)}  # fmt: skip
        self._linear_of_u8 = upload(ctx, LINEAR_OF_U8[None, :])
        self._splat = Pass(ctx, glsl("pixel_splat.frag"), glsl("pixel_splat.vert", DEFINES))
        self._resolve = Pass(ctx, glsl("pixel_resolve.frag", DEFINES))
        self._nearest, self._index = Target.make(ctx, n, n, 1), Target.make(ctx, n, n, 1)
        self._fill = PushPull(ctx, n, n)
        self._map: tuple[Target, Target, Any] | None = None  # points, colours, the framebuffer drawing both
        self._inputs: dict[str, Any] = {}  # the bound map's uploaded textures
        self.n_points = 0  # texels of the bound map (the splat's instances); 0: none bound

    @property
    def takes_display(self) -> bool:
        """Whether maps may come as 8-bit display values (:attr:`GIMap.display`): this warp decodes them itself,
        on the GPU, where it brings the map's radiance (its indirect part is made on the host)."""
        return self.layer == "radiance"

    def bind(self, gi: GIMap) -> Timings:
        """Per GI map: the map and its depth uploaded, and its point cloud drawn from them (module docstring)."""
        sw = Stopwatch()
        ctx, (h, w) = self.ctx, gi.depth.shape
        if h * w >= MAX_POINTS:
            raise ValueError(f"the GL warp takes maps of fewer than {MAX_POINTS} texels, got {w}x{h}")
        shown = gi.display is not None and self.takes_display
        if shown:
            image = ctx.texture((w, h), 3, np.ascontiguousarray(gi.display), dtype="f1")  # texel = byte / 255
        else:
            image = upload(ctx, gi.layer(self.layer))
        if self._map is None or self._map[0].size != (w, h):
            points, colours = Target.make(ctx, w, h, 4), Target.make(ctx, w, h, 4)
            self._map = (points, colours, ctx.framebuffer([points.texture, colours.texture]))
        for texture in self._inputs.values():
            texture.release()
        self._inputs = {"u_depth": upload(ctx, gi.depth), "u_gi": image}
        camera = gi.camera
        uniforms = {"u_inv_view": mat_bytes(np.linalg.inv(camera.view())),
                    "u_focal": tuple(float(np.float32(v)) for v in camera.proj()[[0, 1], [0, 1]])}  # fmt: skip
        both = Target(self._map[0].texture, self._map[2], 4)
        self._cloud[shown].draw(both, self._inputs | {"u_linear_of_u8": self._linear_of_u8}, uniforms)
        self.n_points = w * h
        ctx.finish()
        sw.lap("bind")
        return sw.ms

    def drawn_points(self) -> np.ndarray:
        """The bound map's point cloud as the GPU drew it, read back: per texel (image rows) world x, y, z and the
        pixel's world size over its depth (all 0: background), for comparing with the numpy warp's (tests)."""
        if self._map is None:
            raise RuntimeError("no GI map is bound; call bind() first")
        return self._map[0].read().reshape(-1, 4)

    def draw(self, camera: Camera, textures: dict[str, Any], sw: Stopwatch) -> Target:
        if self._map is None or not self.n_points:
            raise RuntimeError("no GI map is bound; call bind() first")
        self._draw_splat(camera)
        inputs = {"u_index": self._index.texture, "u_colours": self._map[1].texture, "u_mask": textures["di"]}
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
        n_points = self.n_points
        ctx.enable(ctx.BLEND)
        ctx.blend_equation = ctx.MIN
        for target, index in ((self._nearest, False), (self._index, True)):
            target.fbo.clear(EMPTY, EMPTY, EMPTY, EMPTY)
            if n_points:
                inputs = {"u_points": self._map[0].texture} | ({"u_nearest": self._nearest.texture} if index else {})
                self._splat.draw(target, inputs, uniforms | {"u_index": index}, self._splat.vao,
                                 mode=ctx.TRIANGLE_STRIP, vertices=4, instances=n_points)  # fmt: skip
        ctx.blend_equation = ctx.FUNC_ADD
        ctx.disable(ctx.BLEND)
