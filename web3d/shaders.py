"""The Web3D page's WebGL2 programs, from the sources the desktop GL passes compile (no shader text lives in the
page's JavaScript):

- the scene's passes (:mod:`gicore.gl.shaders`, per scene: its light, shadow layout and materials compiled in),
  in ``scene.json``;
- the warps', the hole filling's and the composition's (:mod:`gicore.gl.sources`: ``gicore/gl/glsl/``) and the
  page's own ports (``web3d/glsl/``: GIGAN's input encoding and output decoding), in
  ``shaders.json``, with the values their uniforms take from Python's constants.

Each source is ``#version 330 core`` written in the subset GLSL ES 3.00 shares; :func:`to_es` swaps the version
line and adds precision qualifiers, and that is the whole port.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from baseline_cloudbaking.gl_warp import DEFINES as PIXEL_DEFINES
from baseline_cloudbaking.gl_warp import EMPTY
from gicore.gl.blend import compose_fragment
from gicore.gl.passes import FULLSCREEN_VERTEX
from gicore.gl.renderer import AREA_SAMPLES
from gicore.gl.shaders import SCENE_VERTEX, SHADOW_FRAGMENT, SHADOW_VERTEX, scene_fragment
from gicore.gl.sources import glsl
from gicore.scene import SceneSpec
from gicore.tonemap import LINEAR_OF_U8
from gigan_local.gl_warp import PASSES as STRUCTURE_PASSES
from gigan_local.warp import DEPTH_REL_TOL, fallback_step

FORMAT = "gigan-web-shaders/1"
#: The page's own sources.
PAGE_GLSL = Path(__file__).with_name("glsl")
#: The page's scene passes: the scene program's defines and the colour attachment of the DI output.
PASSES: dict[str, tuple[tuple[str, ...], int]] = {
    "di_gbuffer": (("GBUFFER", "DI"), 4),
    "di": (("DI",), 0),
    "uv": (("UV",), 0),
}
#: Channels of each buffer of the network's input (gigan_local.preprocess).
CHANNELS = {"di": 3, "albedo": 3, "normal": 3, "depth": 1, "mask": 1}
_ES_HEAD = "#version 300 es\nprecision highp float;\nprecision highp int;\n"
_ES_SAMPLERS = "precision highp sampler2DShadow;\nprecision highp sampler2D;\n"


def to_es(source: str) -> str:
    """A ``#version 330 core`` shader as GLSL ES 3.00 (WebGL2): the version line and precision qualifiers."""
    head, rest = source.lstrip().split("\n", 1)
    if head.strip() != "#version 330 core":
        raise ValueError(f"expected a '#version 330 core' shader, got {head!r}")
    return _ES_HEAD + _ES_SAMPLERS + rest


def _program(fragment: str, vertex: str = FULLSCREEN_VERTEX) -> dict[str, str]:
    return {"vertex": to_es(vertex), "fragment": to_es(fragment)}


def scene_programs(spec: SceneSpec, material_rows: int) -> dict[str, dict[str, str]]:
    """The scene's passes the page draws (:data:`PASSES`, each DI pass also for cube-face shadows) and its shadow
    map's, for ``spec``'s light and ``material_rows`` materials."""
    area = spec.light.size > 0
    programs = {}
    for name, (defines, di_location) in PASSES.items():
        for cube in (False, True) if "DI" in defines else (False,):
            fragment = scene_fragment(
                *defines,
                di_location=di_location,
                area_light=area,
                cube_shadow=cube,
                material_rows=material_rows,
                light_samples=AREA_SAMPLES if area else 1,
            )
            programs[name + ("_cube" if cube else "")] = _program(fragment, SCENE_VERTEX)
    programs["shadow"] = _program(SHADOW_FRAGMENT, SHADOW_VERTEX)
    return programs


def encode_writes(buffers: list[str]) -> tuple[int, str]:
    """The encoding's targets and its WRITES: the input's channels (``buffers``' in order), four per target."""
    channels = [f"e_{b}[{k}]" for b in buffers for k in range(CHANNELS[b])]
    targets = -(-len(channels) // 4)
    padded = channels + ["0.0"] * (4 * targets - len(channels))
    writes = " ".join(f"o{t} = vec4({', '.join(padded[4 * t : 4 * t + 4])});" for t in range(targets))
    return targets, writes


def page_shaders(resolution: int, model_input: dict[str, Any]) -> dict[str, Any]:
    """``shaders.json``: the programs of the page's warps, hole filling, composition (tone-mapped for the
    canvas), GIGAN's encoding and decoding for ``model_input`` (``model.json``'s: the buffers, and the albedo floor
    of a demodulated model), and a cloud map's point cloud; the uniforms' values at
    ``resolution`` (the depth test's tolerance and the fallback's coarse step, the splat's empty key, the 8-bit
    inverse tone map's table); and the encoding's channels and targets."""
    programs = {f"structure_{k}": _program(glsl(f"structure_{k}.frag", v)) for k, v in STRUCTURE_PASSES.items()}
    programs |= {k: _program(glsl(f"{k}.frag")) for k in ("pull", "push")}
    programs["pixel_splat"] = _program(glsl("pixel_splat.frag"), glsl("pixel_splat.vert", PIXEL_DEFINES))
    programs["pixel_resolve"] = _program(glsl("pixel_resolve.frag", PIXEL_DEFINES))
    programs["compose"] = _program(compose_fragment("blend", tonemapped=True))
    buffers, albedo_floor = model_input["buffers"], model_input.get("albedo_floor")
    targets, writes = encode_writes(buffers)
    demodulate = {} if albedo_floor is None else {"ALBEDO_FLOOR": float(albedo_floor)}
    encode_defines = {"TARGETS": targets, "WRITES": writes} | demodulate
    programs["encode"] = _program(glsl("encode.frag", encode_defines, PAGE_GLSL))
    programs["decode"] = _program(glsl("decode.frag", demodulate, PAGE_GLSL))
    programs["pixel_cloud"] = _program(glsl("pixel_cloud.frag", {"DISPLAY": None}))
    f32 = np.float32  # as the desktop warp rounds them
    step = fallback_step(resolution, resolution)
    structure = {"u_tol_hi": float(f32(1.0 + DEPTH_REL_TOL)), "u_tol_lo": float(f32(1.0 - DEPTH_REL_TOL))}
    structure |= {"u_inv_step": float(f32(1.0 / step)), "u_step": step}
    encode = {"channels": sum(CHANNELS[b] for b in buffers), "targets": targets}
    return {
        "format": FORMAT,
        "programs": programs,
        "structure": structure,
        "pixel": {"empty": EMPTY, "linear_of_u8": LINEAR_OF_U8.tolist()},
        "encode": encode,
    }
