"""Shader passes over float targets in the process's GL context: what the warps' and the composition's GL
backends draw with (``gigan_local.gl_warp``, ``baseline_cloudbaking.gl_warp``, :mod:`gicore.gl.blend`).

A :class:`Pass` is one program drawn into a :class:`Target`; its inputs are read with ``texelFetch`` (no
filtering, no sampler state), so a texel holds exactly the float32 value its numpy counterpart holds. Texture
rows are the image's rows (row 0 at the top), as :meth:`gicore.gl.GLRenderer.draw_di_raster` draws them, so
numpy arrays upload (:func:`upload`) and read back (:meth:`Target.read`) with no flip. The sources are
:mod:`gicore.gl.sources`'.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gicore.gl.sources import glsl

#: One triangle over the whole viewport (a fullscreen pass draws 3 vertices and no buffer).
FULLSCREEN_VERTEX = glsl("fullscreen.vert")


def upload(ctx: Any, array: np.ndarray) -> Any:
    """An HxW or HxWxC (C <= 4) array as a float32 texture (texel (x, y) = ``array[y, x]``)."""
    a = np.ascontiguousarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or not 1 <= a.shape[2] <= 4:
        raise ValueError(f"a texture takes an HxW or HxWxC array with C <= 4, got {array.shape}")
    return ctx.texture((a.shape[1], a.shape[0]), a.shape[2], a.tobytes(), dtype="f4")


def rewrite(ctx: Any, texture: Any | None, array: np.ndarray) -> Any:
    """``array`` in ``texture`` when its size and channels fit (written over, no new texture), else in a new one
    (:func:`upload`)."""
    a = np.ascontiguousarray(array, dtype=np.float32)
    components = 1 if a.ndim == 2 else a.shape[-1]
    if texture is None or texture.size != (a.shape[1], a.shape[0]) or texture.components != components:
        return upload(ctx, a)
    texture.write(a)  # the array's buffer, not a bytes copy of it
    return texture


@dataclass
class Target:
    """A float32 texture of ``components`` channels and the framebuffer that draws into it."""

    texture: Any
    fbo: Any
    components: int

    @classmethod
    def make(cls, ctx: Any, width: int, height: int, components: int = 4) -> Target:
        texture = ctx.texture((width, height), components, dtype="f4")
        return cls(texture, ctx.framebuffer([texture]), components)

    @property
    def size(self) -> tuple[int, int]:
        return self.texture.size

    def read(self) -> np.ndarray:
        """The target as a new float32 HxWxC array."""
        w, h = self.size
        buf = bytearray(w * h * self.components * 4)
        self.fbo.read_into(buf, components=self.components, dtype="f4")
        return np.frombuffer(buf, dtype=np.float32).reshape(h, w, self.components)


class Pass:
    """A program (``fragment`` with ``vertex``, by default :data:`FULLSCREEN_VERTEX`) that :meth:`draw` runs into
    a target with named textures and uniforms; a uniform the compiler removed is skipped."""

    def __init__(self, ctx: Any, fragment: str, vertex: str = FULLSCREEN_VERTEX):
        self.ctx = ctx
        self.program = ctx.program(vertex_shader=vertex, fragment_shader=fragment)
        self.vao = ctx.vertex_array(self.program, [])

    def draw(
        self,
        target: Target,
        textures: dict[str, Any],
        uniforms: dict[str, Any] | None = None,
        vao: Any | None = None,
        **render: Any,
    ) -> None:
        """Draw into ``target``, texture ``i`` of ``textures`` on unit ``i``: a fullscreen triangle, or ``vao``
        (a vertex array of this pass's program) with ``render`` as ``vertex_array.render``'s arguments."""
        for unit, (name, texture) in enumerate(textures.items()):
            texture.use(unit)
            if name in self.program:
                self.program[name].value = unit
        for name, value in (uniforms or {}).items():
            if name not in self.program:
                continue
            if isinstance(value, bytes):
                self.program[name].write(value)
            else:
                self.program[name].value = value
        target.fbo.use()
        if vao is None:
            self.vao.render(vertices=3)
        else:
            vao.render(**render)
