"""The GPU algorithms' shader sources, one file each in ``gicore/gl/glsl/`` (``#version 330 core``), read by the
desktop GL passes and exported to the Web3D page as GLSL ES 3.00 by ``web3d.export`` (docs/architecture.md,
OpenGL passes):

- ``structure_slack.frag``, ``structure_coarse.frag``, ``structure_mean.frag``, ``structure_warp.frag``: the
  structure-aware warp (``gigan_local.gl_warp``): depth planes, coarse fallback level and its mean, lookup;
- ``pixel_cloud.frag``, ``pixel_splat.vert``, ``pixel_splat.frag``, ``pixel_resolve.frag``: the pixel-level warp's
  point cloud (the bound map and its depth unprojected on the GPU) and splat
  (``baseline_cloudbaking.gl_warp``);
- ``pull.frag``, ``push.frag``: the push-pull hole filling (:mod:`gicore.gl.fill`);
- ``compose.frag``: eq. 1 and the residual composition (:mod:`gicore.gl.blend`);
- ``fullscreen.vert`` and ``tonemap.glsl`` (included by the sources that tone-map).

A source is written in the subset GLSL 330 and GLSL ES 3.00 share (``texelFetch``, no hardware filtering), so
the port changes only the version line and adds precision qualifiers. Constants that Python owns
(``SUBTEXEL``, ``EMPTY``...) are ``#define``s the caller passes, so each has one value.
"""

from __future__ import annotations

import re
from pathlib import Path

#: The folder of the shared sources.
GLSL_DIR = Path(__file__).with_name("glsl")
_INCLUDE = re.compile(r'^#include "([\w.]+)"$', re.MULTILINE)


def define(value: object) -> str:
    """``value`` as a GLSL literal: a float always with a decimal point or an exponent, a bool as 1 or 0."""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, float):
        text = repr(value)
        return text if "." in text or "e" in text else text + ".0"
    return str(value)


def glsl(name: str, defines: dict[str, object] | None = None, folder: Path = GLSL_DIR) -> str:
    """The source ``name`` of ``folder`` with ``#define NAME value`` lines after its version line (a value of
    None defines the name alone) and each ``#include "file"`` replaced by that file of :data:`GLSL_DIR`."""
    head, rest = (folder / name).read_text().split("\n", 1)
    rest = _INCLUDE.sub(lambda m: (GLSL_DIR / m[1]).read_text().rstrip("\n"), rest)
    lines = [f"#define {k}" if v is None else f"#define {k} {define(v)}" for k, v in (defines or {}).items()]
    return "\n".join([head, *lines, rest])
