"""The structure-aware warp (:mod:`gigan_local.warp`, Alg. 1) as a GL pass on the GL renderer's own textures:
the frame's uv pass (GI-camera clip coordinates, position, surface code) and DI stay where they were drawn,
and one fragment pass projects, depth-tests the four bilinear taps and fills invalid pixels, in the order and
float32 arithmetic of :meth:`gigan_local.warp.StructureAwareWarp.resample` (docs/architecture.md,
Structure-aware warping).

Per map, :meth:`GLStructureWarp.bind` uploads the map and its depth (they arrive in host memory from the model or
the network either way) and draws the slope-scaled depth planes from the depth in a pass that computes
:func:`~gigan_local.warp.depth_slack` texel by texel, in the same float32 operations, so the planes are the numpy
warp's to the bit; only the small coarse fallback level and its mean are computed on the host. The taps are
fetched texel by texel (no hardware filtering), with the weights rounded to 1/``SUBTEXEL`` as the numpy warp
rounds them, so both warps read the same texels with the same weights; they differ only where float32 rounding (a
fused multiply-add, a division) moves a weight across a rounding step or a tap across the depth test's bound.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from gicore.camera import Camera
from gicore.gi_map import GIMap, Timings
from gicore.gl.frame import ShaderWarp
from gicore.gl.passes import Pass, Target, rewrite
from gicore.timing import Stopwatch
from gigan_local.warp import DEPTH_REL_TOL, SUBTEXEL, checked_map, checked_options, fallback_level

if TYPE_CHECKING:
    from gicore.gl.renderer import GLRenderer

SLACK_FRAGMENT = """
#version 330 core
uniform sampler2D u_depth;  // the GI camera's linear view depth (0: background)
layout(location = 0) out vec2 o;  // depth - slack, depth + slack; +inf, -inf on background

const float INF = uintBitsToFloat(0x7f800000u);

float axis_step(ivec2 p, ivec2 along, float d) {  // depth_slack along one axis: 0 on the frame's border
    ivec2 a = p - along, b = p + along;
    if (any(lessThan(a, ivec2(0))) || any(greaterThanEqual(b, textureSize(u_depth, 0)))) return 0.0;
    float da = texelFetch(u_depth, a, 0).r, db = texelFetch(u_depth, b, 0).r;
    float s = min(da > 0.0 ? abs(d - da) : INF, db > 0.0 ? abs(db - d) : INF);  // a background neighbour: none
    return s == INF ? 0.0 : s;
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    float d = texelFetch(u_depth, p, 0).r;
    if (!(d > 0.0)) { o = vec2(INF, -INF); return; }
    float slack = axis_step(p, ivec2(1, 0), d) + axis_step(p, ivec2(0, 1), d);
    o = vec2(d - slack, d + slack);
}
"""

WARP_FRAGMENT = f"""
#version 330 core
uniform sampler2D u_uv;        // the uv pass: GI-camera clip (x, y)
uniform sampler2D u_position;  // world position
uniform sampler2D u_code;      // 0 background, 1 an untextured surface, 2 textured
uniform sampler2D u_di;        // the frame's DI (the fallback's base for the radiance layer)
uniform sampler2D u_planes;    // per GI texel: depth - slack, depth + slack (+inf, -inf on background)
uniform sampler2D u_gi;        // the bound layer
uniform sampler2D u_coarse;    // the fallback's coarse level
uniform vec4 u_w_row;          // GI-camera clip w = u_w_row . (p, 1)
uniform float u_near;
uniform float u_tol_hi;        // 1 + DEPTH_REL_TOL and 1 - DEPTH_REL_TOL
uniform float u_tol_lo;
uniform float u_inv_step;      // 1 / GITexture.coarse_step
uniform vec3 u_mean;           // the fallback behind the GI camera and on untextured surfaces
uniform bool u_base;           // add the frame's DI to the fallback (the radiance layer)
layout(location = 0) out vec4 o;  // the layer; alpha: valid (from the map, or background)

vec3 coarse(float x, float y) {{  // StructureAwareWarp._coarse
    ivec2 size = textureSize(u_coarse, 0);
    float cx = clamp((x + 0.5) * u_inv_step - 0.5, 0.0, float(size.x - 1));
    float cy = clamp((y + 0.5) * u_inv_step - 0.5, 0.0, float(size.y - 1));
    float x0 = floor(cx), y0 = floor(cy);
    float fx = cx - x0, fy = cy - y0;
    ivec2 a = ivec2(x0, y0), b = min(a + 1, size - 1);
    vec3 c = texelFetch(u_coarse, a, 0).rgb * ((1.0 - fx) * (1.0 - fy));
    c += texelFetch(u_coarse, ivec2(b.x, a.y), 0).rgb * (fx * (1.0 - fy));
    c += texelFetch(u_coarse, ivec2(a.x, b.y), 0).rgb * ((1.0 - fx) * fy);
    return c + texelFetch(u_coarse, b, 0).rgb * (fx * fy);
}}

void main() {{
    ivec2 p = ivec2(gl_FragCoord.xy);
    float code = texelFetch(u_code, p, 0).r;
    if (code <= 0.5) {{ o = vec4(0.0, 0.0, 0.0, 1.0); return; }}  // background: nothing to warp
    vec3 base = u_base ? texelFetch(u_di, p, 0).rgb : vec3(0.0);
    if (code <= 1.5) {{ o = vec4(u_mean + base, 0.0); return; }}
    vec2 clip = texelFetch(u_uv, p, 0).xy;
    vec3 pos = texelFetch(u_position, p, 0).xyz;
    float w = pos.x * u_w_row.x + pos.y * u_w_row.y + pos.z * u_w_row.z + u_w_row.w;
    bool front = w > u_near;
    float half_w = 0.5 / (front ? w : 1.0);
    ivec2 size = textureSize(u_gi, 0);
    vec2 last = vec2(size - 1);
    float x = (clip.x * half_w + 0.5) * float(size.x) - 0.5;
    float y = (0.5 - clip.y * half_w) * float(size.y) - 0.5;
    bool ok = front && x >= -0.5 && x <= last.x + 0.5 && y >= -0.5 && y <= last.y + 0.5;
    x = clamp(x, 0.0, last.x);  // clamp to edge (the fallback reads the clamped uv too)
    y = clamp(y, 0.0, last.y);
    float x0 = floor(x), y0 = floor(y);
    float fx = roundEven((x - x0) * {SUBTEXEL:.1f}) * {1.0 / SUBTEXEL!r};
    float fy = roundEven((y - y0) * {SUBTEXEL:.1f}) * {1.0 / SUBTEXEL!r};
    ivec2 a = ivec2(x0, y0), b = min(a + 1, size - 1);
    ivec2 taps[4] = ivec2[4](a, ivec2(b.x, a.y), ivec2(a.x, b.y), b);
    float gx = 1.0 - fx, gy = 1.0 - fy;
    float weights[4] = float[4](gx * gy, fx * gy, gx * fy, fx * fy);
    float total = 0.0;
    for (int i = 0; i < 4; ++i) {{  // |d - w| <= tol * w + slack on [d - slack, d + slack]
        vec2 plane = texelFetch(u_planes, taps[i], 0).xy;
        if (!(plane.x <= w * u_tol_hi && plane.y >= w * u_tol_lo)) weights[i] = 0.0;
        total += weights[i];
    }}
    if (ok && total > 0.0) {{
        vec3 sum = vec3(0.0);
        for (int i = 0; i < 4; ++i) sum += texelFetch(u_gi, taps[i], 0).rgb * (weights[i] / total);
        o = vec4(sum, 1.0);
        return;
    }}
    o = vec4((front ? coarse(x, y) : u_mean) + base, 0.0);
}}
"""


class GLStructureWarp(ShaderWarp):
    """Alg. 1 in a GL pass on ``renderer`` (a :class:`gicore.gl.GLRenderer`): :meth:`bind` a GI map once, then
    :meth:`~gicore.gl.frame.ShaderWarp.frame` composes each frame; the same ``layer`` and ``depth_rel_tol`` as
    :class:`~gigan_local.warp.StructureAwareWarp`."""

    name = "structure"
    raster = "uv"
    stages = ("bind", "warp")

    def __init__(self, renderer: GLRenderer, layer: str = "radiance", depth_rel_tol: float = DEPTH_REL_TOL):
        super().__init__(renderer)
        self.layer, self.depth_rel_tol = checked_options(layer, depth_rel_tol)
        self._pass = Pass(self.ctx, WARP_FRAGMENT)
        self._slack = Pass(self.ctx, SLACK_FRAGMENT)
        n = renderer.resolution
        self._out = Target.make(self.ctx, n, n, 4)
        self._planes: Target | None = None
        self._textures: dict[str, Any] = {}
        self._uniforms: dict[str, Any] = {}

    def bind(self, gi: GIMap) -> Timings:
        """Per GI map: its layer and depth uploaded, the depth planes drawn from the depth (:data:`SLACK_FRAGMENT`),
        the coarse fallback level computed and uploaded, and the GI camera's projection set in the renderer's
        vertex shader."""
        sw = Stopwatch()
        image, depth, indirect = checked_map(gi.camera, gi.layer(self.layer), gi.depth, gi.indirect)
        if image.shape[2] != 3:
            raise ValueError(f"the GL warp takes a 3-channel GI map, got {image.shape[2]} channels")
        coarse, step, mean = fallback_level(indirect, depth > 0)
        textures = self._textures
        for name, array in (("u_depth", depth), ("u_gi", image), ("u_coarse", coarse)):
            textures[name] = rewrite(self.ctx, textures.get(name), array)
        height, width = depth.shape
        if self._planes is None or self._planes.size != (width, height):
            self._planes = Target.make(self.ctx, width, height, 2)
        self._slack.draw(self._planes, {"u_depth": textures["u_depth"]})
        textures["u_planes"] = self._planes.texture
        self.renderer.set_texcoord_projection(gi.camera)
        tol = self.depth_rel_tol
        f32 = np.float32  # each constant as numpy rounds a python float against a float32 array
        self._uniforms = {
            "u_w_row": tuple(float(v) for v in gi.camera.view_proj()[3].astype(f32)),
            "u_near": float(f32(gi.camera.near)),
            "u_tol_hi": float(f32(1.0 + tol)),
            "u_tol_lo": float(f32(1.0 - tol)),
            "u_inv_step": float(f32(1.0 / step)),
            "u_mean": tuple(float(v) for v in mean),
            "u_base": self.layer == "radiance",
        }
        self.ctx.finish()
        sw.lap("bind")
        return sw.ms

    def draw(self, camera: Camera, textures: dict[str, Any], sw: Stopwatch) -> Target:
        if not self._textures:
            raise RuntimeError("no GI map is bound; call bind() first")
        frame = {"u_uv": textures["uv"], "u_position": textures["position"], "u_code": textures["code"]}
        self._pass.draw(self._out, frame | {"u_di": textures["di"]} | self._textures, self._uniforms)
        self.lap(sw, "warp")
        return self._out
