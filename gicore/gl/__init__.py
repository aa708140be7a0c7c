"""OpenGL side of the testbed: what a Web3D client rasterises per frame (docs/architecture.md, OpenGL passes).

``gicore.render`` (Mitsuba) path-traces; this package rasterises the per-frame client passes with
moderngl on a headless EGL context. :mod:`gicore.gl.context` owns the process's one context,
:mod:`gicore.gl.renderer` the passes (:class:`GLRenderer`, parallel to ``gicore.render.Renderer``),
:mod:`gicore.gl.shadow` the shadow map, :mod:`gicore.gl.shaders` the GLSL, :mod:`gicore.gl.brdf` the materials'
tables, :mod:`gicore.gl.lod` the levels of detail, :mod:`gicore.gl.edges` the silhouettes that comparisons leave
out and :mod:`gicore.gl.fidelity` the comparison with Mitsuba (``python -m gicore.gl.fidelity``).
"""

from gicore.gl.context import RasterUnavailable, gl_available, gl_context, gl_info
from gicore.gl.renderer import GLRenderer

__all__ = ["GLRenderer", "RasterUnavailable", "gl_available", "gl_context", "gl_info"]
