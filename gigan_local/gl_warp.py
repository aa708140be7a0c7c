"""The structure-aware warp (:mod:`gigan_local.warp`, Alg. 1) in GL passes on the GL renderer's own textures:
the frame's uv pass (GI-camera clip coordinates, position, surface code) and DI stay where they were drawn,
and one fragment pass (``structure_warp.frag``) projects, depth-tests the four bilinear taps and fills invalid
pixels, in the order and float32 arithmetic of :meth:`gigan_local.warp.StructureAwareWarp.resample`
(docs/architecture.md, Structure-aware warping). The Web3D page draws the same sources (:mod:`gicore.gl.sources`).

Per map, :meth:`GLStructureWarp.bind` uploads the map, its indirect light and its depth (they arrive in host
memory from the model or the network either way) and draws what the lookups read: the slope-scaled depth planes
(``structure_slack.frag``: :func:`~gigan_local.warp.depth_slack` texel by texel, in the same float32 operations,
so the planes are the numpy warp's to the bit), the fallback's coarse level (``structure_coarse.frag``'s block
means, filled by the push-pull passes of :mod:`gicore.gl.fill`) and its mean (``structure_mean.frag``), summed
in another order than numpy's (a few ulps). The taps are fetched texel by texel (no hardware filtering), with the
weights rounded to 1/``SUBTEXEL`` as the numpy warp rounds them, so both warps read the same texels with the same
weights; they differ only where float32 rounding (a fused multiply-add, a division) moves a weight across a
rounding step or a tap across the depth test's bound.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from gicore.camera import Camera
from gicore.gi_map import GIMap, Timings
from gicore.gl.fill import PushPull
from gicore.gl.frame import ShaderWarp
from gicore.gl.passes import Pass, Target, rewrite
from gicore.gl.sources import glsl
from gicore.timing import Stopwatch
from gigan_local.warp import DEPTH_REL_TOL, SUBTEXEL, checked_map, checked_options, fallback_step

if TYPE_CHECKING:
    from gicore.gl.renderer import GLRenderer

#: The structure-aware warp's fragment shaders (``structure_NAME.frag``) and their defines.
PASSES: dict[str, dict[str, object]] = {"slack": {}, "coarse": {}, "mean": {}, "warp": {"SUBTEXEL": SUBTEXEL}}


class GLStructureWarp(ShaderWarp):
    """Alg. 1 in GL passes on ``renderer`` (a :class:`gicore.gl.GLRenderer`): :meth:`bind` a GI map once, then
    :meth:`~gicore.gl.frame.ShaderWarp.frame` composes each frame; the same ``layer`` and ``depth_rel_tol`` as
    :class:`~gigan_local.warp.StructureAwareWarp`."""

    name = "structure"
    raster = "uv"
    stages = ("bind", "warp")

    def __init__(self, renderer: GLRenderer, layer: str = "radiance", depth_rel_tol: float = DEPTH_REL_TOL):
        super().__init__(renderer)
        self.layer, self.depth_rel_tol = checked_options(layer, depth_rel_tol)
        self._passes = {k: Pass(self.ctx, glsl(f"structure_{k}.frag", v)) for k, v in PASSES.items()}
        n = renderer.resolution
        self._out = Target.make(self.ctx, n, n, 4)
        self._mean = Target.make(self.ctx, 1, 1, 4)
        self._planes: Target | None = None
        self._fill: PushPull | None = None
        self._sums: Target | None = None
        self._textures: dict[str, Any] = {}
        self._uniforms: dict[str, Any] = {}

    def bind(self, gi: GIMap) -> Timings:
        """Per GI map: its layer, indirect light and depth uploaded, the depth planes, the coarse fallback level and
        its mean drawn from them, and the GI camera's projection set in the renderer's vertex shader."""
        sw = Stopwatch()
        image, depth, indirect = checked_map(gi.camera, gi.layer(self.layer), gi.depth, gi.indirect)
        if image.shape[2] != 3:
            raise ValueError(f"the GL warp takes a 3-channel GI map, got {image.shape[2]} channels")
        textures = self._textures
        for name, array in (("u_depth", depth), ("u_gi", image), ("u_indirect", indirect)):
            textures[name] = rewrite(self.ctx, textures.get(name), array)
        height, width = depth.shape
        step = fallback_step(height, width)
        self._draw_levels(width, height, step)
        textures |= {"u_planes": self._planes.texture, "u_mean": self._mean.texture}
        self.renderer.set_texcoord_projection(gi.camera)
        tol = self.depth_rel_tol
        f32 = np.float32  # each constant as numpy rounds a python float against a float32 array
        self._uniforms = {
            "u_w_row": tuple(float(v) for v in gi.camera.view_proj()[3].astype(f32)),
            "u_near": float(f32(gi.camera.near)),
            "u_tol_hi": float(f32(1.0 + tol)),
            "u_tol_lo": float(f32(1.0 - tol)),
            "u_inv_step": float(f32(1.0 / step)),
            "u_base": self.layer == "radiance",
        }
        self.ctx.finish()
        sw.lap("bind")
        return sw.ms

    def _draw_levels(self, width: int, height: int, step: int) -> None:
        """The depth planes, the coarse level (its block means filled by push-pull) and its mean, from the bound
        depth and indirect light; targets made anew when the map's size changes."""
        ctx, textures = self.ctx, self._textures
        coarse = (-(-width // step), -(-height // step))
        if self._planes is None or self._planes.size != (width, height):
            self._planes = Target.make(ctx, width, height, 2)
        if self._fill is None or self._fill.size != coarse:
            self._fill = PushPull(ctx, *coarse)
            self._sums = Target.make(ctx, *coarse, 4)
            self._blocks = ctx.framebuffer([self._fill.level0.texture, self._sums.texture])
        self._passes["slack"].draw(self._planes, {"u_depth": textures["u_depth"]})
        blocks = Target(self._fill.level0.texture, self._blocks, 4)  # two outputs: the level and the block sums
        inputs = {"u_indirect": textures["u_indirect"], "u_depth": textures["u_depth"]}
        self._passes["coarse"].draw(blocks, inputs, {"u_step": step})
        textures["u_coarse"] = self._fill.run().texture
        self._passes["mean"].draw(self._mean, {"u_sums": self._sums.texture})

    def draw(self, camera: Camera, textures: dict[str, Any], sw: Stopwatch) -> Target:
        if not self._uniforms:
            raise RuntimeError("no GI map is bound; call bind() first")
        frame = {"u_uv": textures["uv"], "u_position": textures["position"], "u_code": textures["code"]}
        self._passes["warp"].draw(self._out, frame | {"u_di": textures["di"]} | self._textures, self._uniforms)
        self.lap(sw, "warp")
        return self._out
