"""The process's one OpenGL context: moderngl on headless EGL (no X server).

On a CPU-only machine EGL gives Mesa's llvmpipe (software rasteriser, JIT-compiled through LLVM); on a
machine with a GPU, the vendor's driver. Nothing else in the project creates a GL context: every
:class:`gicore.gl.renderer.GLRenderer` of a process shares this one, on the thread that opened it.

When no context opens (moderngl not installed, no EGL library, no usable device), :func:`gl_context`
raises :class:`RasterUnavailable` with a one-line reason, so a caller can fall back to Mitsuba
(``gicore.render``) and say why.
"""

from __future__ import annotations

from typing import Any

#: OpenGL version the shaders need (GLSL 330 core).
REQUIRED_GL = 330
INSTALL_HINT = "apt-get install -y libegl1 libgl1-mesa-dri libegl-mesa0; pip install moderngl"


class RasterUnavailable(RuntimeError):
    """No headless OpenGL context can be opened here; ``str(err)`` is a one-line reason with the fix."""


_context: Any = None
_failure: str | None = None


def gl_context() -> Any:
    """The process's ``moderngl.Context`` (opened on first use); :class:`RasterUnavailable` if none opens.

    A failure is remembered: later calls raise the same reason at once instead of probing EGL again.
    """
    global _context, _failure
    if _context is not None:
        return _context
    if _failure is not None:
        raise RasterUnavailable(_failure)
    try:
        import moderngl
    except ImportError as err:
        _failure = f"moderngl is not installed ({err}); {INSTALL_HINT}"
        raise RasterUnavailable(_failure) from None
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=REQUIRED_GL)
    except Exception as err:  # glcontext raises plain Exceptions for a missing libEGL or device
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        version = f"{REQUIRED_GL // 100}.{REQUIRED_GL % 100 // 10}"
        _failure = f"no headless EGL OpenGL {version} context opens ({reason}); {INSTALL_HINT}"
        raise RasterUnavailable(_failure) from None
    ctx.gc_mode = "auto"  # GL objects are freed when their Python wrappers are collected
    _context = ctx
    return ctx


def gl_available() -> tuple[bool, str]:
    """(True, GL_RENDERER) when a context opens, else (False, the reason)."""
    try:
        return True, gl_info()["GL_RENDERER"]
    except RasterUnavailable as err:
        return False, str(err)


def gl_info() -> dict[str, str]:
    """GL_RENDERER, GL_VENDOR and GL_VERSION of the process's context (opening it if needed)."""
    info = gl_context().info
    return {key: str(info[key]) for key in ("GL_RENDERER", "GL_VENDOR", "GL_VERSION")}
