"""The pixel-level warp (:mod:`baseline_cloudbaking.warp`) as GL passes on the GL renderer's own textures: the
bound map's point cloud is splatted into the frame and its holes are filled by a push-pull pyramid, with the
frame's surface mask (the DI target's alpha) read where the renderer drew it (docs/architecture.md,
Pixel-level warping).

Per map, :meth:`GLPixelWarp.bind` builds the numpy warp's :class:`~baseline_cloudbaking.warp.PointCloud` and
uploads its points (one instance each) and colours: the map arrives decoded in host memory either way. Per
frame:

1. **splat**: each point is projected as the numpy warp projects it and drawn as its ``k x k`` square, a quad
   whose corners lie on pixel edges (so every covered pixel centre is half a pixel inside it), clipped to the
   frame; two passes with ``MIN`` blending on float32 targets keep, per pixel, the nearest point's depth and
   then the smallest index among the points at that depth: the numpy warp's packed key (depth, then index),
   exactly, where a depth equals the numpy warp's to the bit.
2. **fill**: the winners' colours where the surface mask is set, then :func:`gicore.fill.push_pull`'s pull
   (2x2 weight-normalised sums, zero-padded) and push (nearest upsampling) passes in its order of operations,
   the background set to 0.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from baseline_cloudbaking.warp import FOOTPRINT_EPS, MAX_FOOTPRINT, PointCloud
from gicore.camera import Camera
from gicore.gi_map import LAYERS, GIMap, Timings
from gicore.gl.frame import ShaderWarp
from gicore.gl.passes import Pass, Target, upload
from gicore.gl.shaders import mat_bytes
from gicore.timing import Stopwatch

if TYPE_CHECKING:
    from gicore.gl.renderer import GLRenderer

#: Points a map may have: their indices are float32 values of a MIN-blended target, exact below 2^24.
MAX_POINTS = 1 << 24
#: The empty pixel of the splat targets (larger than any depth or index).
EMPTY = 3.0e38

SPLAT_VERTEX = f"""
#version 330 core
uniform mat4 u_vp;          // the target camera's M_p . M_v
uniform float u_near;
uniform float u_focal_px;   // the target camera's focal length in pixels
uniform vec2 u_size;        // target width, height
in vec3 in_point;           // per instance: a world point ...
in float in_dof;            // ... and its source pixel's world size over its depth
flat out float v_depth;
flat out float v_index;
void main() {{
    vec4 clip = u_vp * vec4(in_point, 1.0);
    v_depth = clip.w;
    v_index = float(gl_InstanceID);
    if (!(clip.w > u_near)) {{ gl_Position = vec4(2.0, 2.0, 0.0, 1.0); return; }}  // dropped: no area
    float half_w = 0.5 / clip.w;
    float col = (clip.x * half_w + 0.5) * u_size.x;
    float row = (0.5 - clip.y * half_w) * u_size.y;
    float scale = in_dof * u_focal_px / clip.w;
    float k = max(ceil(min(scale, {MAX_FOOTPRINT:.1f}) - {FOOTPRINT_EPS!r}), 1.0);
    vec2 origin = floor(vec2(col, row) + (0.5 - 0.5 * k));
    vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));  // a triangle strip
    vec2 xy = clamp(origin + corner * k, vec2(0.0), u_size);  // window x, y = image column, row
    gl_Position = vec4(2.0 * xy / u_size - 1.0, 0.0, 1.0);
}}
"""

SPLAT_FRAGMENT = """
#version 330 core
uniform sampler2D u_nearest;  // the first pass's nearest depth (the second pass)
uniform bool u_index;
flat in float v_depth;
flat in float v_index;
layout(location = 0) out vec4 o;
void main() {
    if (!u_index) { o = vec4(v_depth); return; }
    if (v_depth != texelFetch(u_nearest, ivec2(gl_FragCoord.xy), 0).r) discard;
    o = vec4(v_index);
}
"""

RESOLVE_FRAGMENT = f"""
#version 330 core
uniform sampler2D u_index;    // the winning point per pixel (EMPTY: none)
uniform sampler2D u_colours;  // point i's colour at texel (i % width, i / width)
uniform sampler2D u_di;       // alpha: the frame's surface mask
layout(location = 0) out vec4 o;  // colour x valid, valid: the push-pull's finest level
void main() {{
    ivec2 p = ivec2(gl_FragCoord.xy);
    float i = texelFetch(u_index, p, 0).r;
    if (i >= {EMPTY:.1e} || !(texelFetch(u_di, p, 0).a > 0.0)) {{ o = vec4(0.0); return; }}
    int n = int(i), width = textureSize(u_colours, 0).x;
    o = vec4(texelFetch(u_colours, ivec2(n % width, n / width), 0).rgb, 1.0);
}}
"""

PULL_FRAGMENT = """
#version 330 core
uniform sampler2D u_finer;  // premultiplied colour, weight in alpha
layout(location = 0) out vec4 o;
vec4 at(ivec2 t, ivec2 size) { return all(lessThan(t, size)) ? texelFetch(u_finer, t, 0) : vec4(0.0); }
void main() {  // gicore.fill.push_pull's 2x2 sums, in its order
    ivec2 p = 2 * ivec2(gl_FragCoord.xy), size = textureSize(u_finer, 0);
    vec4 s = at(p, size) + at(p + ivec2(0, 1), size) + at(p + ivec2(1, 0), size) + at(p + ivec2(1, 1), size);
    float w = min(s.a, 1.0);
    o = vec4(s.rgb * (w / max(s.a, 1e-12)), w);
}
"""

PUSH_FRAGMENT = """
#version 330 core
uniform sampler2D u_level;    // this level of the pull (premultiplied colour, weight)
uniform sampler2D u_coarser;  // the filled coarser level; at the top, the pull's last level
uniform sampler2D u_di;       // alpha: the frame's surface mask (the finest level)
uniform bool u_top;
uniform bool u_finest;
layout(location = 0) out vec4 o;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 own = texelFetch(u_level, p, 0);
    vec4 up = texelFetch(u_coarser, p / 2, 0);
    vec3 coarse = u_top ? up.rgb / max(up.a, 1e-12) : up.rgb;
    o = vec4(own.rgb + (1.0 - own.a) * coarse, own.a);
    if (u_finest && !(texelFetch(u_di, p, 0).a > 0.0)) o = vec4(0.0, 0.0, 0.0, 1.0);  // background: valid, 0
}
"""


def pyramid_sizes(width: int, height: int) -> list[tuple[int, int]]:
    """The push-pull's level sizes, finest first: halved (rounded up) until one pixel is left."""
    sizes = [(width, height)]
    while max(sizes[-1]) > 1:
        w, h = sizes[-1]
        sizes.append((-(-w // 2), -(-h // 2)))
    return sizes


class GLPixelWarp(ShaderWarp):
    """Pixel-level warping in GL passes on ``renderer`` (a :class:`gicore.gl.GLRenderer`), the cloud-baking
    client's warp with ``--warp-backend gl``: :meth:`bind` a map's point cloud once, then
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
        self._splat = Pass(ctx, SPLAT_FRAGMENT, SPLAT_VERTEX)
        self._resolve, self._pull, self._push = (Pass(ctx, f) for f in (RESOLVE_FRAGMENT, PULL_FRAGMENT, PUSH_FRAGMENT))
        self._nearest, self._index = Target.make(ctx, n, n, 1), Target.make(ctx, n, n, 1)
        sizes = pyramid_sizes(n, n)
        self._pulled = [Target.make(ctx, w, h, 4) for w, h in sizes]
        self._pushed = [Target.make(ctx, w, h, 4) for w, h in sizes[:-1]]
        self._cloud: Any = None
        self.cloud: PointCloud | None = None
        self._colours: Any = None

    def bind(self, gi: GIMap) -> Timings:
        """Per GI map: the numpy warp's point cloud, its points and colours uploaded."""
        sw = Stopwatch()
        cloud = PointCloud(gi.layer(self.layer), gi.depth, gi.camera)
        n_points = cloud.points.shape[1]
        if cloud.channels != 3 or n_points >= MAX_POINTS:
            raise ValueError(f"the GL warp takes a 3-channel map of fewer than {MAX_POINTS} points")
        data = np.concatenate([cloud.points[:3].T, cloud.src_depth_over_focal[:, None]], axis=1)
        points = np.ascontiguousarray(data, dtype=np.float32).tobytes()
        buffer = self.ctx.buffer(points or bytes(16))  # a GL buffer is never empty (a blank map has no point)
        self._cloud = self.ctx.vertex_array(
            self._splat.program, [(buffer, "3f 1f/i", "in_point", "in_dof")], skip_errors=True
        )
        width = gi.camera.width
        colours = np.zeros((-(-max(n_points, 1) // width) * width, 3), np.float32)
        colours[:n_points] = cloud.colours
        self._colours = upload(self.ctx, colours.reshape(-1, width, 3))
        self.cloud = cloud
        self.ctx.finish()
        sw.lap("bind")
        return sw.ms

    def draw(self, camera: Camera, textures: dict[str, Any], sw: Stopwatch) -> Target:
        if self.cloud is None:
            raise RuntimeError("no GI map is bound; call bind() first")
        self._draw_splat(camera)
        self._resolve.draw(self._pulled[0], {"u_index": self._index.texture, "u_colours": self._colours,
                                             "u_di": textures["di"]})  # fmt: skip
        self.lap(sw, "splat")
        for finer, coarser in zip(self._pulled, self._pulled[1:]):
            self._pull.draw(coarser, {"u_finer": finer.texture})
        top = len(self._pushed) - 1
        for level in range(top, -1, -1):
            coarser = self._pulled[-1] if level == top else self._pushed[level + 1]
            inputs = {"u_level": self._pulled[level].texture, "u_coarser": coarser.texture, "u_di": textures["di"]}
            self._push.draw(self._pushed[level], inputs, {"u_top": level == top, "u_finest": level == 0})
        self.lap(sw, "fill")
        return self._pushed[0] if self._pushed else self._pulled[0]

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
        n_points = self.cloud.points.shape[1]
        ctx.enable(ctx.BLEND)
        ctx.blend_equation = ctx.MIN
        for target, index in ((self._nearest, False), (self._index, True)):
            target.fbo.clear(EMPTY, EMPTY, EMPTY, EMPTY)
            if n_points:
                inputs = {"u_nearest": self._nearest.texture} if index else {}
                self._splat.draw(target, inputs, uniforms | {"u_index": index}, self._cloud,
                                 mode=ctx.TRIANGLE_STRIP, vertices=4, instances=n_points)  # fmt: skip
        ctx.blend_equation = ctx.FUNC_ADD
        ctx.disable(ctx.BLEND)
