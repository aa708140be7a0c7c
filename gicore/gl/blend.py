"""The composition (:mod:`gicore.blend`: eq. 1's blend, or the residual composition) as a GL pass, the last
stage of a frame whose warp runs in shaders: the frame's DI and the warped layer are the renderer's and the
warp's textures, and the composed frame, with the warp's valid mask in alpha, is the only thing read back
(docs/architecture.md, Composition). The shader is ``compose.frag`` (:mod:`gicore.gl.sources`), which the Web3D
page draws too.

Eq. 1 is ``tau * di + (1 - tau) * gi`` with the weights rounded to float32 as numpy rounds them, so it equals
:func:`gicore.blend.blend` up to float32 rounding; the residual composition adds the warped indirect layer
(its ``di_of_gi`` is 0, as the client loop's is).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gicore.blend import COMPOSITIONS
from gicore.gl.passes import Pass, Target
from gicore.gl.sources import glsl


def compose_fragment(composition: str, tonemapped: bool = False) -> str:
    """``compose.frag`` for ``composition`` (:data:`gicore.blend.COMPOSITIONS`); ``tonemapped``: the frame
    tone-mapped for a screen (the Web3D page's canvas), else linear radiance with the valid mask in alpha."""
    if composition not in COMPOSITIONS:
        raise ValueError(f"composition must be one of {COMPOSITIONS}, got {composition!r}")
    defines = {"RESIDUAL": None} if composition == "residual" else {}
    return glsl("compose.frag", defines | ({"TONEMAP": None} if tonemapped else {}))


class GLCompose:
    """Composes a frame of ``width`` x ``height`` in ``ctx`` (:meth:`draw`) and reads it back (:meth:`read`)."""

    def __init__(self, ctx: Any, width: int, height: int):
        self.ctx = ctx
        self.target = Target.make(ctx, width, height, 4)
        self._passes: dict[str, Pass] = {}

    def draw(self, di: Any, warped: Any, composition: str = "blend", tau: float = 0.0) -> Target:
        """The composed frame of the DI texture ``di`` and the warped texture ``warped`` (valid in alpha)."""
        if not 0.0 <= tau <= 1.0:
            raise ValueError(f"tau must lie in [0, 1], got {tau}")
        if composition not in self._passes:
            self._passes[composition] = Pass(self.ctx, compose_fragment(composition))
        # numpy rounds the python weights to float32 where they meet a float32 array
        weights = {"u_tau": float(np.float32(tau)), "u_one_minus_tau": float(np.float32(1.0 - tau))}
        self._passes[composition].draw(self.target, {"u_di": di, "u_warped": warped}, weights)
        return self.target

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """The composed frame (HxWx3 linear radiance) and the warp's valid mask (HxW bool)."""
        rgba = self.target.read()
        return rgba[..., :3], rgba[..., 3] > 0.5
