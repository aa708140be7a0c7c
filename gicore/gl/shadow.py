"""The GL renderer's shadow map (docs/architecture.md, OpenGL passes): its views fitted to a light and the
scene's casters (one perspective frustum, or six cube faces in one atlas when the light is inside the casters'
bounding sphere), and the depth atlas they render into with the samplers the DI pass reads it through.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from gicore.camera import NEAR_MIN, Camera
from gicore.gl.shaders import SHADOW_FRAGMENT, SHADOW_VERTEX, mat_bytes

#: Shadow-map texels per image pixel along a side (:func:`shadow_size_for`): at 256² a 512² map costs 3 to 6 ms
#: less per moving-light frame than 1024² on one core (llvmpipe) and its DI stays closer to 256-spp Mitsuba DI than
#: the 1-spp Mitsuba DI it replaces (SSIM 0.9848 / 0.9715 / 0.9775 vs 0.9798 / 0.9506 / 0.9704 on lung_plane /
#: vessels_plane / digestive_cornell; 1024²: 0.9869 / 0.9714 / 0.9800).
SHADOW_TEXELS_PER_PIXEL = 2


def shadow_size_for(resolution: int) -> int:
    """Side of the fitted shadow map (texels) for square images of ``resolution``: :data:`SHADOW_TEXELS_PER_PIXEL`
    per pixel, within [512, 4096]: cube faces get half of it each and cover 90° apiece, which needs the floor
    (a light among the objects at 64²: DI SSIM 0.93 against Mitsuba with 256², >= 0.94 with 512²)."""
    return min(max(SHADOW_TEXELS_PER_PIXEL * int(resolution), 512), 4096)


#: Level of the shadow map's casters when the renderer has levels (``lod`` other than "full"): level 2 (1/4 of
#: the triangles) renders the 1024² map in 7 ms instead of 18 (lung_plane) and changes DI by at most 1e-3
#: SSIM against full-detail casters (relative mean |delta| <= 1.2e-3; lung and vessels, 3 lights x 2 views);
#: coarser casters save no more time (the map's fragments are the floor).
SHADOW_LOD = 2


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit geometric normals (counter-clockwise winding), +y for degenerate faces."""
    tri = vertices[faces].astype(np.float32)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), np.float32([0, 1, 0])).astype(np.float32)


def _up_for(direction: np.ndarray) -> tuple[float, float, float]:
    """An up vector far from parallel to ``direction``."""
    d = np.abs(direction) / np.linalg.norm(direction)
    return (0.0, 0.0, 1.0) if d[1] > 0.9 else (0.0, 1.0, 0.0)


def _views(views: list, tan_half: float, tile: int, atlas: tuple[int, int], blocker_min: float, far: float) -> dict:
    """A shadow setup: view-projection matrices (one tile of ``tile`` texels each in an ``atlas``), the
    tangent-plane size of a texel, the nearest distance from the light a blocker can have, and the
    distance that depth 1 stands for (the map stores distance / far)."""
    texel = [2 * tan_half / tile] * len(views)
    return {"views": views, "texel": texel, "tile": tile, "atlas": atlas, "blocker_min": blocker_min, "far": far}


#: Per object: bounding-sphere centre and radius, the plane (normal, point) of a flat environment quad (None for
#: the spec's objects) and the bounding box's corners.
Bounds = tuple[np.ndarray, float, np.ndarray | None, np.ndarray]


def object_bounds(objects: list, n_spec: int) -> list[Bounds]:
    """:data:`Bounds` of each object; the first ``n_spec`` are the spec's, the rest environment quads."""
    out = []
    for i, obj in enumerate(objects):
        v = obj.mesh.vertices.astype(np.float64)
        lo, hi = v.min(axis=0), v.max(axis=0)
        centre = (lo + hi) / 2.0
        plane = None if i < n_spec else np.stack([face_normals(v, obj.mesh.faces[:1])[0], v[0]])
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        out.append((centre, float(np.linalg.norm(v - centre, axis=1).max()), plane, corners))
    return out


def fit_shadow_views(bounds: list[Bounds], light: np.ndarray, size: int) -> dict[str, Any]:
    """The shadow views for a light at ``light`` (``size`` texels a side): matrices, texel sizes, the atlas layout.

    Casters: the spec's objects, and the environment quads the light is behind (a quad shadows only
    what lies beyond it); their bounding sphere (a union of the objects' spheres) is what a fitted
    frustum must hold. Its far plane reaches the farthest corner of any object's box."""
    casters = [(c, r) for c, r, plane, _ in bounds if plane is None or float(np.dot(plane[0], light - plane[1])) < 0]
    lo = np.min([c - r for c, r in casters], axis=0)
    hi = np.max([c + r for c, r in casters], axis=0)
    centre = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(c - centre)) + r for c, r in casters) + 1e-4
    corners = np.concatenate([b[3] for b in bounds])
    far = float(np.linalg.norm(corners - light, axis=1).max()) * 1.01 + 1e-3
    dist = float(np.linalg.norm(centre - light))
    if dist > 1.02 * radius:
        tan_half = math.tan(math.asin(radius / dist)) * (1.0 + 4.0 / size)  # + 2 texels for the PCF kernel
        near = max(0.5 * (dist - radius), NEAR_MIN * 10)
        fov = math.degrees(2 * math.atan(tan_half))
        cam = Camera(tuple(light), tuple(centre), _up_for(centre - light), fov, near, max(far, 2 * near), size, size)
        return _views([cam.view_proj()], tan_half, size, (size, size), dist - radius, max(far, 2 * near))
    tile = max(16, size // 2)
    tan_half = 1.0 + 8.0 / tile  # 90 degrees + 4 texels, so that kernels near a face's edge stay inside
    fov = math.degrees(2 * math.atan(tan_half))
    near = max(1e-4 * far, NEAR_MIN * 10)
    views = []
    for axis in np.eye(3):
        for sign in (1.0, -1.0):
            target = tuple(light + sign * axis)
            views.append(Camera(tuple(light), target, _up_for(axis), fov, near, far, tile, tile).view_proj())
    return _views(views, tan_half, tile, (3 * tile, 2 * tile), max(near, 0.01 * radius), far)


class ShadowMap:
    """The depth atlas of a light's shadow views (made again when their layout changes), its comparing and raw
    samplers, and the program that renders the casters' depth into it from ``vbo``/``ibo`` (the scene's
    interleaved vertices, position first, and its triangles)."""

    def __init__(self, ctx: Any, vbo: Any, ibo: Any) -> None:
        self.ctx = ctx
        self.program = ctx.program(vertex_shader=SHADOW_VERTEX, fragment_shader=SHADOW_FRAGMENT)
        self.vao = ctx.vertex_array(self.program, [(vbo, "3f 28x", "in_pos")], ibo, skip_errors=True)
        #: The views rendered last (:func:`fit_shadow_views`), empty before the first.
        self.setup: dict[str, Any] = {}
        self.samplers: tuple[Any, Any] | None = None
        self._fbo: Any = None

    def render(self, setup: dict[str, Any], light: tuple[float, float, float], draw: Callable[[Any], None]) -> None:
        """Render the casters' depth for the light at ``light`` in ``setup``'s views; ``draw(vao)`` draws the
        casters through the program's vertex array."""
        ctx = self.ctx
        if self.setup.get("atlas") != setup["atlas"]:
            tex = ctx.depth_texture(setup["atlas"])
            tex.repeat_x = tex.repeat_y = False
            compare = ctx.sampler(repeat_x=False, repeat_y=False, filter=(ctx.LINEAR, ctx.LINEAR), compare_func="<=")
            raw = ctx.sampler(repeat_x=False, repeat_y=False, filter=(ctx.NEAREST, ctx.NEAREST), compare_func="")
            compare.texture = raw.texture = tex
            self._fbo = ctx.framebuffer(depth_attachment=tex)
            self.samplers = (compare, raw)
        fbo = self._fbo
        fbo.use()
        fbo.clear(depth=1.0)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        prog = self.program
        prog["u_light"].value = light
        prog["u_far"].value = setup["far"]
        tile = setup["tile"]
        for face, vp in enumerate(setup["views"]):
            fbo.viewport = ((face % 3) * tile, (face // 3) * tile, tile, tile)
            prog["u_vp"].write(mat_bytes(vp))
            draw(self.vao)
        self.setup = setup

    @property
    def cube(self) -> bool:
        """Whether the views are the six cube faces."""
        return len(self.setup["views"]) == 6

    def uniforms(self) -> dict[str, Any]:
        """The DI pass's shadow uniforms; binds the comparing sampler to unit 1 and the raw one to unit 3."""
        compare, raw = self.samplers
        compare.use(location=1)
        raw.use(location=3)
        s = self.setup
        return {
            "u_shadow": 1,
            "u_shadow_raw": 3,
            "u_shadow_far": s["far"],
            "u_shadow_vp": b"".join(mat_bytes(v) for v in s["views"]) + bytes(64 * (6 - len(s["views"]))),
            "u_shadow_texel": np.float32(s["texel"] + [0.0] * (6 - len(s["texel"]))).tobytes(),
            "u_shadow_size": s["tile"],
            "u_blocker_min": s["blocker_min"],
        }
