"""A client frame whose warp and composition run in shaders on a :class:`gicore.gl.GLRenderer`'s own textures:
the DI and the warp's pass are drawn (:meth:`~gicore.gl.GLRenderer.draw_di_raster`), the warp's passes read
them where they were drawn, the composition (:mod:`gicore.gl.blend`) reads the DI and the warped layer, and
only the composed frame comes back to host memory (docs/architecture.md, OpenGL passes).

:class:`ShaderWarp` is the base of the warps' GL backends (``gigan_local.gl_warp``,
``baseline_cloudbaking.gl_warp``): each brings :meth:`ShaderWarp.draw`, its passes from the frame's textures
to the warped layer. Stage times wait for the GPU (``glFinish``) at the end of each stage, so each stage holds
its own GPU work and none is pushed into the read-back. :func:`open_client_raster` opens a client's raster
renderer and :func:`warp_backend` picks the backend of its warp.
"""

from __future__ import annotations

import sys
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from gicore.gl.blend import GLCompose
from gicore.gl.context import RasterUnavailable, gl_info
from gicore.gl.passes import Target
from gicore.run_config import CLIENT_LOD, WARP_BACKENDS, open_raster
from gicore.timing import Stopwatch

if TYPE_CHECKING:
    from gicore.camera import Camera
    from gicore.gl.renderer import GLRenderer
    from gicore.render import Renderer
    from gicore.scene import SceneSpec

#: GL_RENDERER names (lower case) of rasterisers that run on the CPU.
CPU_RASTERISERS = ("llvmpipe", "softpipe", "lavapipe", "swiftshader")


def open_client_raster(
    choice: str, spec: SceneSpec, resolution: int, path_renderer: Renderer | None, lod: str | int = CLIENT_LOD
) -> tuple[Any, str]:
    """The renderer of a client's per-frame raster passes for ``--renderer choice`` and the name of the one that
    runs them: a :class:`GLRenderer` of ``spec`` at ``resolution`` and ``lod`` where a GL context opens, else
    ``path_renderer`` (Mitsuba's; None where the caller has not opened one yet) after one warning line
    (:func:`gicore.run_config.open_raster`)."""
    from gicore.gl.renderer import GLRenderer  # the renderer's modules load only for a client that opens one

    gl = partial(GLRenderer, spec, resolution, lod=lod)
    return open_raster(choice, path_renderer, gl, RasterUnavailable)


def warp_backend(choice: str, renderer: str, warn: bool = False) -> str:
    """The backend (``numpy`` or ``gl``) of a client's warp and composition for ``--warp-backend choice``
    (:data:`gicore.run_config.WARP_BACKENDS`) when its raster passes run on ``renderer`` (``gl`` or ``mitsuba``).

    ``auto`` is the measured default per renderer: ``gl`` where GL renders on a GPU; ``numpy`` on Mitsuba and on
    a CPU rasteriser (:data:`CPU_RASTERISERS`), where the shaders run no faster than numpy (docs/architecture.md,
    OpenGL passes). ``gl`` without the GL renderer (no GL context opened) is ``numpy``, after one warning line
    when ``warn``."""
    if choice not in WARP_BACKENDS:
        raise ValueError(f"warp backend must be one of {WARP_BACKENDS}, got {choice!r}")
    if choice == "numpy" or (renderer != "gl" and choice == "auto"):
        return "numpy"
    if renderer != "gl":
        if warn:
            print("warning: warp backend gl needs the GL renderer, using numpy", file=sys.stderr, flush=True)
        return "numpy"
    if choice == "gl":
        return "gl"
    name = gl_info()["GL_RENDERER"].lower()
    return "numpy" if any(cpu in name for cpu in CPU_RASTERISERS) else "gl"


class ShaderWarp:
    """A warp of the bound map whose per-frame work runs in ``renderer``'s GL context (a
    :class:`gicore.loop.Warp`). Subclasses set ``name``, ``layer``, ``raster`` and ``stages`` and implement
    ``bind`` and :meth:`draw`."""

    name: str
    layer: str
    raster: str
    stages: tuple[str, ...]

    def __init__(self, renderer: GLRenderer):
        self.renderer = renderer
        self.ctx = renderer.ctx
        n = renderer.resolution
        self._compose = GLCompose(self.ctx, n, n)

    def draw(self, camera: Camera, textures: dict[str, Any], sw: Stopwatch) -> Target:
        """The warped layer at ``camera`` (RGBA: the layer, alpha 1 where it came from the map or on background,
        0 where from the fallback or hole filling) from the frame's ``textures`` (``draw_di_raster``), lapping
        ``sw`` at the end of each of its per-frame stages."""
        raise NotImplementedError

    def lap(self, sw: Stopwatch, stage: str) -> None:
        """Close ``stage`` once the GPU has done its work."""
        self.ctx.finish()
        sw.lap(stage)

    def frame(
        self, renderer: Renderer, camera: Camera, light: Any, composition: str, tau: float, seed: int
    ) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
        """One composed frame at ``camera`` (:meth:`gicore.loop.Warp.frame`; the raster draws no noise, so
        ``seed`` is unused): (HxWx3 linear radiance, HxW valid mask, ms of ``di``, the warp's per-frame stages and
        ``compose``, the read-back included)."""
        if renderer is not self.renderer:
            raise ValueError("a GL warp draws its frames with the GL renderer it was made on; pass that renderer")
        sw = Stopwatch()
        textures = self.renderer.draw_di_raster(camera, light, self.raster)
        self.lap(sw, "di")
        warped = self.draw(camera, textures, sw)
        self._compose.draw(textures["di"], warped.texture, composition, tau)
        image, valid = self._compose.read()
        sw.lap("compose")
        return image, valid, sw.ms

    def warped(self, camera: Camera, light: Any) -> tuple[np.ndarray, np.ndarray]:
        """The bound layer at ``camera`` read back (HxWx3, HxW valid mask): what the numpy warp returns, for
        comparing the two (tests, ``bench warp``)."""
        textures = self.renderer.draw_di_raster(camera, light, self.raster)
        rgba = self.draw(camera, textures, Stopwatch()).read()
        return rgba[..., :3], rgba[..., 3] > 0.5
