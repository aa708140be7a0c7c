"""OpenGL rasterisation of a scene spec: what a Web3D client renders per frame (docs/architecture.md,
OpenGL passes).

:class:`GLRenderer` mirrors the per-frame passes of :class:`gicore.render.Renderer` (Mitsuba) with the same
signatures and outputs, so a client can hold either: :meth:`~GLRenderer.render_gbuffers`,
:meth:`~GLRenderer.render_di` (with a shadow map), :meth:`~GLRenderer.render_uv` (the structure-aware warp's
pass), :meth:`~GLRenderer.render_depth` and :meth:`~GLRenderer.render_di_raster` (a shown frame's DI and its
warp's pass in one geometry pass). A rasteriser samples pixel centres, so every pass equals Mitsuba's
centre-sampled one; outputs are float32 HxWxC arrays, row 0 at the top. Geometry, every level of detail
included (:mod:`gicore.gl.lod`; docs/architecture.md, Level of detail), is uploaded once; closed meshes are
drawn with back faces culled. The shadow map (:mod:`gicore.gl.shadow`: perspective, or six cube faces in one
atlas when the light is inside the casters' bounding sphere) is rendered once per light position and reused
while the light stays.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from typing import Any

import numpy as np

from gicore.buffers import DATASET_BUFFERS, GBUFFERS, check_buffer_names, check_raster
from gicore.camera import Camera
from gicore.geometry import SceneObject, scene_objects
from gicore.gl.brdf import ETA, TABLE_RES, roughplastic_tables
from gicore.gl.context import gl_context
from gicore.gl.lod import (
    LOD_BOUND,
    LOD_CHANNELS,
    LOD_RATIOS,
    SHOWN_LOD_BOUND,
    ErrorModel,
    LevelMesh,
    calibrate,
    calibration_views,
    lod_errors,
    mesh_levels,
)
from gicore.gl.shaders import DIFFUSE_ROW, EMITTER_ROW, MATERIAL_VEC4S, SCENE_VERTEX, mat_bytes, scene_fragment
from gicore.gl.shadow import (
    SHADOW_LOD,
    Bounds,
    ShadowMap,
    face_normals,
    fit_shadow_views,
    object_bounds,
    shadow_size_for,
)
from gicore.scene import SceneSpec

#: Albedo of the area light's quad: Mitsuba gives an emitter without a BSDF a black diffuse one.
EMITTER_ALBEDO = 0.0
#: K x K points on an area light for its unshadowed light.
AREA_SAMPLES = 2
#: The passes: the scene program's defines and the colour attachments (of the four float targets) written.
#: Targets: 0 albedo or uv, 1 normal, 2 position, 3 depth or the uv pass's surface code, 4 DI.
_PASSES = {
    "gbuffer": (("GBUFFER",), (0, 1, 2, 3)),
    "di": (("DI",), (4,)),
    "di_gbuffer": (("GBUFFER", "DI"), (0, 1, 2, 3, 4)),
    "uv": (("UV",), (0, 2, 3)),
    "depth": (("DEPTH",), (3,)),
    "di_uv": (("UV", "DI"), (0, 2, 3, 4)),
}
#: Where each G-buffer is read back: (attachment, components) in the G-buffer passes.
_GBUFFER_READS = {"albedo": (0, 3), "normal": (1, 3), "position": (2, 3), "depth": (3, 1)}
#: Clip y negated: the image is rendered upside down, so that GL's bottom-up rows read back as an image's
#: top-down rows, with no flip or copy (and window-space winding reversed: front faces are clockwise).
_FLIP_Y = np.diag([1.0, -1.0, 1.0, 1.0])


def _checked_bound(name: str, bound: dict[str, float]) -> dict[str, float]:
    """A copy of ``bound`` (an ``"auto"`` level-of-detail bound) after checking its channels and values."""
    if set(bound) - set(LOD_CHANNELS) or not all(v >= 0 for v in bound.values()):
        raise ValueError(f"{name} must map some of {LOD_CHANNELS} to numbers >= 0, got {bound}")
    return dict(bound)


def _closed(mesh) -> bool:
    """A watertight mesh wound counter-clockwise seen from outside (positive signed volume): seen from
    outside, its back faces are always hidden behind its front faces."""
    if not mesh.is_watertight():
        return False
    v = mesh.vertices.astype(np.float64)[mesh.faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum()) > 0.0


class GLRenderer:
    """Rasterises one scene spec at a fixed square ``resolution`` (see the module docstring).

    ``shadow_size``: side of the fitted shadow map in texels (default :func:`shadow_size_for` the resolution).
    ``lod``: ``"full"``, a level (index into
    ``gicore.gl.lod.LOD_RATIOS``) or ``"auto"``; ``shadow_lod``: the shadow casters' level (default
    :data:`SHADOW_LOD`; level 0 for a ``"full"`` renderer, which uploads no other); ``lod_bound``: the
    ``"auto"`` bound per G-buffer error channel (default ``gicore.gl.lod.LOD_BOUND``), ``shown_lod_bound`` the
    one of the passes that are only shown (default ``gicore.gl.lod.SHOWN_LOD_BOUND``). Raises
    :class:`gicore.gl.context.RasterUnavailable` when no GL context opens.
    """

    name = "gl"

    def __init__(
        self,
        spec: SceneSpec,
        resolution: int | None = None,
        shadow_size: int | None = None,
        lod: str | int = "full",
        shadow_lod: int | None = None,
        lod_bound: dict[str, float] | None = None,
        shown_lod_bound: dict[str, float] | None = None,
    ):
        self.spec = spec
        self.resolution = spec.resolution if resolution is None else int(resolution)
        if not 1 <= self.resolution <= 8192:
            raise ValueError(f"resolution must be an integer in [1, 8192], got {resolution}")
        if shadow_size is None:
            shadow_size = shadow_size_for(self.resolution)
        if not 16 <= shadow_size <= 8192:
            raise ValueError(f"shadow_size must lie in [16, 8192], got {shadow_size}")
        self.shadow_size = int(shadow_size)
        self.ctx = ctx = gl_context()
        self.objects: list[SceneObject] = scene_objects(spec)
        self.n_triangles = sum(o.mesh.n_triangles for o in self.objects)
        if not (lod in ("full", "auto") or (isinstance(lod, int) and 0 <= lod < len(LOD_RATIOS))):
            raise ValueError(f"lod must be 'full', 'auto' or a level in [0, {len(LOD_RATIOS) - 1}], got {lod!r}")
        #: The fraction of triangles each uploaded level keeps; "full" uploads level 0 only.
        self.lod_ratios = (1.0,) if lod == "full" else LOD_RATIOS
        self._lod: str | int = "full"
        self.lod = lod
        #: The G-buffer error bound of ``lod="auto"`` per channel (``gicore.gl.lod.LOD_BOUND``), and the one of
        #: the passes that are only shown (``gicore.gl.lod.SHOWN_LOD_BOUND``).
        self.lod_bound = _checked_bound("lod_bound", LOD_BOUND if lod_bound is None else lod_bound)
        self.shown_lod_bound = _checked_bound(
            "shown_lod_bound", SHOWN_LOD_BOUND if shown_lod_bound is None else shown_lod_bound
        )
        #: ``lod="auto"``'s calibrated error model (:class:`gicore.gl.lod.ErrorModel`), made on first need.
        self.lod_model: ErrorModel | None = None
        self.shadow_lod = min(SHADOW_LOD if shadow_lod is None else int(shadow_lod), len(self.lod_ratios) - 1)
        #: The level the last pass drew.
        self.last_level = 0
        #: Shadow maps rendered so far (a static light renders one).
        self.shadow_updates = 0
        # :meth:`gpu_draw_ms`'s GL timer query, whether it times the passes, and the last pass's GPU ms
        self._timer: Any = None
        self._gpu_timing = False
        self._draw_ms: float | None = None
        self._upload_geometry()
        self._programs: dict[tuple[str, bool], Any] = {}
        self._shadow = ShadowMap(ctx, self._vbo, self._ibo)
        size = (self.resolution, self.resolution)
        # textures rather than renderbuffers, so that shaders can read a pass where it was drawn
        # (:meth:`draw_di_raster`); on llvmpipe drawing into either costs the same
        self._targets = [ctx.texture(size, 1 if i == 3 else 4, dtype="f4") for i in range(5)]
        self._depth = ctx.depth_renderbuffer(size)
        self._pixels: Any = None  # the pixel buffer read-backs go through (:meth:`_read_many`)
        self._fbos = {
            name: ctx.framebuffer([self._targets[i] for i in attachments], self._depth)
            for name, (_, attachments) in _PASSES.items()
        }
        self._shadow_key: tuple | None = None
        self._light: tuple[float, float, float] | None = None
        self._uv_projection: np.ndarray | None = None
        self._bounds_cache: list | None = None
        self._set_light(None)
        if lod == "auto":
            self.calibrate_lod()

    # -- setup -----------------------------------------------------------------------------------
    def _upload_geometry(self) -> None:
        """One interleaved vertex buffer (position, normal, albedo + material row), one index buffer, and
        the texture coordinates in a buffer of their own (rewritten by :meth:`set_texcoords`)."""
        ctx = self.ctx
        roughness = sorted({o.roughness for o in self.objects if o.roughness is not None})
        rows = {r: i for i, r in enumerate(roughness)}
        table = np.zeros((max(1, len(roughness)), 4 * MATERIAL_VEC4S), dtype=np.float32)
        for r, i in rows.items():
            transmittance, internal = roughplastic_tables(r)
            table[i, :TABLE_RES], table[i, TABLE_RES], table[i, TABLE_RES + 1] = transmittance, r, 1.0 / (1 - internal)
        self._materials = table.tobytes()  # the shaders' uniform array u_materials

        # every level of every object in one vertex and one index buffer, uploaded once: level 0 (the meshes
        # themselves) first, so that an object's full-detail vertices keep one range (set_texcoords); a
        # coarser level adds vertices only for the objects it decimates, the others reuse their level 0
        per_object = [mesh_levels(o.mesh, self.lod_ratios) for o in self.objects]
        self._decimated = [len(levels) > 1 and levels[-1] is not levels[0] for levels in per_object]
        closed = {o.name: _closed(o.mesh) for o in self.objects}
        chunks: list[np.ndarray] = []
        self._ranges = {}
        full_faces: dict[str, np.ndarray] = {}
        level_faces: list[dict[bool, list[np.ndarray]]] = []
        base = 0
        for level in range(len(self.lod_ratios)):
            faces_of: dict[bool, list[np.ndarray]] = {True: [], False: []}
            for obj, levels in zip(self.objects, per_object):
                if level > 0 and levels[level] is levels[0]:
                    faces_of[closed[obj.name]].append(full_faces[obj.name])
                    continue
                data, faces, source = self._vertex_data(obj, levels[level], rows)
                chunks.append(data)
                faces = faces.astype(np.int64) + base
                faces_of[closed[obj.name]].append(faces)
                if level == 0:
                    full_faces[obj.name] = faces
                    self._ranges[obj.name] = (base, len(data), source, len(obj.mesh.vertices))
                base += len(data)
            level_faces.append(faces_of)
        self._n_vertices = base
        self._vbo = ctx.buffer(np.concatenate(chunks).tobytes())
        # per level: closed meshes first, drawn with back faces culled (never visible from outside: half the
        # triangles), then the others, two-sided. A decimated closed mesh is drawn as its full mesh is.
        indices, self._draw_ranges, first = [], [], 0
        for faces_of in level_faces:
            culled, rest = (np.concatenate(faces_of[c] or [np.zeros((0, 3), np.int64)]) for c in (True, False))
            indices += [culled, rest]
            self._draw_ranges.append((first, 3 * len(culled), 3 * len(rest)))
            first += 3 * (len(culled) + len(rest))
        self._ibo = ctx.buffer(np.concatenate(indices).astype(np.uint32).tobytes())
        #: Triangles of each level (level 0: the scene's meshes).
        self.level_triangles = [(n_closed + n_rest) // 3 for _, n_closed, n_rest in self._draw_ranges]
        self._uv_vbo = ctx.buffer(reserve=8 * base)
        self._uv_vbo.clear()
        # the area light's quad: 6 vertices rewritten when the light moves; no texture coordinates
        self._emitter_vbo = ctx.buffer(reserve=6 * 40)
        self._emitter_uv = ctx.buffer(reserve=6 * 8)
        self._emitter_uv.clear()
        self._vaos: dict[tuple[str, bool], tuple[Any, Any]] = {}

    @staticmethod
    def _vertex_data(obj: SceneObject, level: LevelMesh, rows: dict[float, int]) -> tuple:
        """(vertex data N x 10: position, normal, albedo, material row; faces into it; the mesh vertex of each
        data vertex, or None where they are the mesh's own) of one level of one object."""
        mesh = level.mesh
        if obj.roughness is None:  # flat: each corner its own vertex with the face's geometric normal
            vertices = mesh.vertices[mesh.faces].reshape(-1, 3)
            normals = np.repeat(face_normals(mesh.vertices, mesh.faces), 3, axis=0)
            source = mesh.faces.ravel()
            faces = np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)
            row = DIFFUSE_ROW
        else:  # smooth: shared vertices with smooth normals (the area-weighted ones Mitsuba gets, at level 0)
            vertices, normals, source, faces = mesh.vertices, level.normals, None, mesh.faces
            row = rows[obj.roughness]
        data = np.empty((len(vertices), 10), dtype=np.float32)
        data[:, 0:3], data[:, 3:6], data[:, 6:9], data[:, 9] = vertices, normals, obj.albedo, row
        return data, faces, source

    def _program(self, name: str, cube: bool) -> Any:
        """The scene program of pass ``name`` (with ``cube``-face shadows for DI), compiled on first use."""
        key = (name, cube)
        if key not in self._programs:
            defines, attachments = _PASSES[name]
            source = scene_fragment(
                *defines,
                di_location=attachments.index(4) if 4 in attachments else 0,
                area_light=self.spec.light.size > 0,
                cube_shadow=cube,
                material_rows=len(self._materials) // (16 * MATERIAL_VEC4S),
                light_samples=AREA_SAMPLES if self.spec.light.size > 0 else 1,
            )
            self._programs[key] = self.ctx.program(vertex_shader=SCENE_VERTEX, fragment_shader=source)
        return self._programs[key]

    def _vao(self, key: tuple[str, bool]) -> tuple[Any, Any]:
        if key not in self._vaos:
            prog = self._program(*key)
            layout = "3f 3f 4f", "in_pos", "in_nrm", "in_mat"
            self._vaos[key] = (
                self.ctx.vertex_array(
                    prog, [(self._vbo, *layout), (self._uv_vbo, "2f", "in_uv")], self._ibo, skip_errors=True
                ),
                self.ctx.vertex_array(
                    prog, [(self._emitter_vbo, *layout), (self._emitter_uv, "2f", "in_uv")], skip_errors=True
                ),
            )
        return self._vaos[key]

    # -- state -----------------------------------------------------------------------------------
    def _check_camera(self, camera: Camera) -> None:
        if (camera.width, camera.height) != (self.resolution, self.resolution):
            n = self.resolution
            raise ValueError(f"camera is {camera.width}x{camera.height} but this renderer renders {n}x{n}")

    def _set_light(self, position) -> tuple[float, float, float]:
        """Move the light; ``None`` means the spec's rest position (as in ``gicore.render``)."""
        position = tuple(self.spec.light.position) if position is None else tuple(float(x) for x in position)
        if position == self._light:
            return position
        if len(position) != 3 or not np.all(np.isfinite(position)):
            raise ValueError(f"light position must be 3 finite numbers, got {position}")
        self._light = position
        size = self.spec.light.size
        if size > 0:  # Mitsuba's rectangle: centred on the light, side ``size``, normal -y
            h = size / 2.0
            corners = np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]]) + position
            quad = corners[[0, 1, 2, 0, 2, 3]]
            data = np.empty((6, 10), dtype=np.float32)
            data[:, 0:3], data[:, 3:6], data[:, 6:9], data[:, 9] = quad, (0, -1, 0), EMITTER_ALBEDO, EMITTER_ROW
            self._emitter_vbo.write(data.tobytes())
        return position

    def set_texcoords(self, name: str, uv: np.ndarray) -> None:
        """Replace the per-vertex texture coordinates of object ``name`` (N x 2, N its mesh's vertices)."""
        if name not in self._ranges:
            raise KeyError(f"no object {name!r}; objects: {[o.name for o in self.objects]}")
        start, count, source, n_mesh = self._ranges[name]
        uv = np.ascontiguousarray(uv, dtype=np.float32)
        if uv.shape != (n_mesh, 2):
            raise ValueError(f"texcoords for {name!r} must be (n_vertices, 2), got {uv.shape}")
        data = uv if source is None else uv[source]
        self._uv_vbo.write(np.ascontiguousarray(data).tobytes(), offset=8 * start)
        self._uv_projection = None

    def set_texcoord_projection(self, camera: Camera | None) -> None:
        """Make every vertex's coordinates ``camera``'s clip (x, y) (eq. 5 before the divide), computed in
        the vertex shader: the same values the warp uploads with :meth:`set_texcoords`, without the upload.
        ``None`` goes back to the uploaded coordinates."""
        self._uv_projection = None if camera is None else camera.view_proj()

    # -- level of detail ---------------------------------------------------------------------------
    @property
    def lod(self) -> str | int:
        """``"full"`` (level 0), a level (an index into :attr:`lod_ratios`) or ``"auto"``."""
        return self._lod

    @lod.setter
    def lod(self, value: str | int) -> None:
        n = len(self.lod_ratios)
        fixed = isinstance(value, int | np.integer) and not isinstance(value, bool) and 0 <= value < n
        if not (value == "full" or (value == "auto" and n > 1) or fixed):
            raise ValueError(f"lod must be 'full', 'auto' or a level in [0, {n - 1}], got {value!r}")
        self._lod = int(value) if fixed else value

    def level_for(self, camera: Camera, shown: bool = False) -> int:
        """The level a pass at ``camera`` draws (see the module docstring); ``shown``: a pass that is only
        shown, whose ``"auto"`` level keeps to :attr:`shown_lod_bound`."""
        if self._lod == "full":
            return 0
        if self._lod == "auto":
            return self.calibrate_lod().level(camera, self.shown_lod_bound if shown else self.lod_bound)
        return int(self._lod)

    def level_error(self, camera: Camera, shown: bool = False) -> tuple[int, dict[str, float]]:
        """The level a pass at ``camera`` draws (:meth:`level_for`) and its G-buffer error against full detail
        there (:func:`gicore.gl.lod.lod_errors`): what the renderer's ``lod`` costs at that view."""
        level = self.level_for(camera, shown)
        at_level, full = (self._gbuffers(self._draw("gbuffer", camera, k)) for k in (level, 0))
        return level, lod_errors(at_level, full)

    def calibrate_lod(self) -> ErrorModel:
        """The calibrated error model of ``lod="auto"`` (measured on first call, see :mod:`gicore.gl.lod`)."""
        if self.lod_model is None:
            centre = np.mean([b[0] for b, decimated in zip(self._bounds(), self._decimated) if decimated] or [0], 0)
            views = calibration_views(self.spec, self.resolution)
            model = calibrate(
                lambda cam, level: self._gbuffers(self._draw("gbuffer", cam, level)),
                len(self.lod_ratios),
                views,
                np.broadcast_to(centre, (3,)),
            )
            self.lod_model = model
        return self.lod_model

    # -- shadows ---------------------------------------------------------------------------------
    def _bounds(self) -> list[Bounds]:
        """Per object, :func:`object_bounds`; computed once."""
        if self._bounds_cache is None:
            self._bounds_cache = object_bounds(self.objects, len(self.spec.objects))
        return self._bounds_cache

    def _shadow_views(self, light: np.ndarray) -> dict[str, Any]:
        """The shadow views for a light at ``light`` (:func:`fit_shadow_views` on this scene's objects)."""
        return fit_shadow_views(self._bounds(), light, self.shadow_size)

    def _ensure_shadow(self) -> None:
        """Render the shadow map for the current light unless it is already there."""
        key = (self._light,)
        if key == self._shadow_key:
            return
        setup = self._shadow_views(np.asarray(self._light, dtype=np.float64))
        self._shadow.render(setup, self._light, lambda vao: self._render_scene(vao, self.shadow_lod))
        self._shadow_key = key
        self.shadow_updates += 1

    # -- passes ----------------------------------------------------------------------------------
    def _draw(self, name: str, camera: Camera, level: int | None = None) -> Any:
        """Run pass ``name`` at ``camera`` (at ``level``, default :meth:`level_for`); returns its framebuffer
        (read it with :meth:`_read`). Inside :meth:`gpu_draw_ms` the draw calls are timed on the GPU."""
        if not self._gpu_timing:
            return self._draw_calls(name, camera, level)
        if self._timer is None:
            self._timer = self.ctx.query(time=True)
        with self._timer:
            fbo = self._draw_calls(name, camera, level)
        self._draw_ms = self._timer.elapsed / 1e6
        return fbo

    def gpu_draw_ms(self, run: Callable[[], Any]) -> float:
        """GPU time in ms of the draw calls (its shadow map included) of the last pass ``run()`` draws here, by a
        GL timer query: the pass without its read-back to host memory, what a client that keeps it on the GPU
        pays. Time the call's wall clock apart: reading the query waits for the GPU before the read-back would."""
        self._gpu_timing, self._draw_ms = True, None
        try:
            run()
        finally:
            self._gpu_timing = False
        if self._draw_ms is None:
            raise RuntimeError("the timed call drew no pass on this renderer")
        return self._draw_ms

    def _draw_calls(self, name: str, camera: Camera, level: int | None) -> Any:
        self._check_camera(camera)
        di = "DI" in _PASSES[name][0]
        if di:
            self._ensure_shadow()
        variant = (name, di and self._shadow.cube)
        ctx, prog = self.ctx, self._program(*variant)
        uniforms: dict[str, Any] = {
            "u_view_proj": mat_bytes(_FLIP_Y @ camera.view_proj()),
            "u_view": mat_bytes(camera.view()),
            "u_eye": camera.origin,
            "u_project_uv": self._uv_projection is not None,
        }
        if self._uv_projection is not None:
            uniforms["u_uv_proj"] = mat_bytes(self._uv_projection)
        if di:
            uniforms |= self._di_uniforms() | self._shadow.uniforms()
        for key, value in uniforms.items():
            uniform = prog.get(key, None)
            if uniform is None:  # not used by this variant (compiled out)
                continue
            if isinstance(value, bytes):  # matrices and arrays; the compiler may shorten an array to the
                uniform.write(value[: uniform.array_length * uniform.element_size])  # elements it reads
            else:
                uniform.value = value
        fbo = self._fbos[name]
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE | ctx.BLEND)
        ctx.front_face = "cw"
        scene, emitter = self._vao(variant)
        if level is None:
            uploaded_uv = name in ("uv", "di_uv") and self._uv_projection is None  # full meshes' coordinates
            level = 0 if uploaded_uv else self.level_for(camera)
        self._render_scene(scene, level)
        self.last_level = level
        if self.spec.light.size > 0:
            emitter.render(vertices=6)
        ctx.front_face = "ccw"
        return fbo

    def _render_scene(self, vao: Any, level: int = 0) -> None:
        """Draw the scene's triangles at ``level``: closed meshes with back faces culled, the others two-sided."""
        ctx = self.ctx
        first, n_closed, n_rest = self._draw_ranges[level]
        if n_closed:
            ctx.enable(ctx.CULL_FACE)
            vao.render(vertices=n_closed, first=first)
            ctx.disable(ctx.CULL_FACE)
        if n_rest:
            vao.render(vertices=n_rest, first=first + n_closed)

    def _di_uniforms(self) -> dict[str, Any]:
        """The DI pass's light and material uniforms (the shadow's come from :class:`ShadowMap`)."""
        light = self.spec.light
        area = light.size > 0
        k = AREA_SAMPLES if area else 1
        return {
            "u_light": self._light,
            "u_intensity": light.intensity / (k * k),
            "u_radiance": light.intensity / light.size**2 if area else 0.0,
            "u_light_size": light.size,
            "u_eta": ETA,
            "u_materials": self._materials,
        }

    def _read_many(self, fbo: Any, reads: dict[str, tuple[int, int]]) -> dict[str, np.ndarray]:
        """For each of ``reads`` (name: attachment, components), the leading ``components`` of that colour attachment
        as a new float32 HxWxC array (row 0 at the top: the pass rendered upside down). They are copied on the
        device into one pixel buffer and brought to the host in one transfer: one wait for the pass, not one each."""
        n = self.resolution
        sizes = {name: n * n * components * 4 for name, (_, components) in reads.items()}
        total = sum(sizes.values())
        if self._pixels is None or self._pixels.size < total:
            self._pixels = self.ctx.buffer(reserve=total)
        offset = 0
        for name, (attachment, components) in reads.items():
            fbo.read_into(self._pixels, components=components, attachment=attachment, dtype="f4", write_offset=offset)
            offset += sizes[name]
        host = bytearray(total)
        self._pixels.read_into(host, size=total)
        out, offset = {}, 0
        for name, (_, components) in reads.items():
            out[name] = np.frombuffer(host, np.float32, n * n * components, offset).reshape(n, n, components)
            offset += sizes[name]
        return out

    def _gbuffers(self, fbo: Any, wanted: Collection[str] = GBUFFERS, di: bool = False) -> dict[str, np.ndarray]:
        """The ``wanted`` G-buffers (:data:`gicore.buffers.GBUFFERS`) of a pass into ``fbo``, and its DI (attachment
        4) with ``di``; only what is asked for is read back (the mask comes from the depth)."""
        needed = {*wanted, "depth"} if "mask" in wanted else set(wanted)
        reads = {name: place for name, place in _GBUFFER_READS.items() if name in needed}
        out = self._read_many(fbo, ({"di": (4, 3)} if di else {}) | reads)
        if "mask" in wanted:
            out["mask"] = (out["depth"] > 0).astype(np.float32)
        return {name: out[name] for name in out if name in wanted or name == "di"}

    def render_gbuffers(self, camera: Camera, seed: int = 0, centre: bool = True) -> dict[str, np.ndarray]:
        """Albedo, view-space normal (GL), linear view depth, world position and mask, at pixel centres.

        ``seed`` and ``centre`` exist for parity with ``gicore.render``: a rasteriser always samples the
        pixel centre (Mitsuba's ``centre=True``) and has nothing random."""
        return self._gbuffers(self._draw("gbuffer", camera))

    def render_di(self, camera: Camera, light=None, spp: int = 1, seed: int = 0) -> np.ndarray:
        """Direct illumination (diffuse + glossy, shadow-mapped) at pixel centres; deterministic (``spp``
        and ``seed`` exist for parity with ``gicore.render``)."""
        self._set_light(light)
        return self._read_many(self._draw("di", camera), {"di": (0, 3)})["di"]

    def render_di_gbuffers(
        self, camera: Camera, light=None, seed: int = 0, centre: bool = True, buffers: Collection[str] = GBUFFERS
    ) -> dict[str, np.ndarray]:
        """DI and the G-buffers in one pass (five render targets); only the G-buffers ``buffers`` names are read
        back (other names are ignored)."""
        self._set_light(light)
        return self._gbuffers(self._draw("di_gbuffer", camera), buffers, di=True)

    def render_uv(self, camera: Camera) -> dict[str, np.ndarray]:
        """The warp's pass at ``camera``, as ``gicore.render.Renderer.render_uv``: ``uv`` (HxWx2, the bound
        coordinates interpolated over each triangle; 0 off textured surfaces), ``position`` (HxWx3),
        ``mask`` and ``textured`` (HxW bool; the area light's quad is a surface but not textured)."""
        return self._uv_pass(self._draw("uv", camera))

    def _uv_pass(self, fbo: Any, di: bool = False) -> dict[str, np.ndarray]:
        """The uv pass's outputs from ``fbo``, whose attachments 0-2 hold them (``uv`` and ``di_uv``), and with
        ``di`` the DI (attachment 3 of ``di_uv``)."""
        out = self._read_many(fbo, {"uv": (0, 2), "position": (1, 3), "code": (2, 1)} | ({"di": (3, 3)} if di else {}))
        code = out.pop("code")[..., 0]
        return out | {"mask": code > 0.5, "textured": code > 1.5}

    def render_di_raster(
        self, camera: Camera, light=None, raster: str | None = None, seed: int = 0
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """A shown frame's DI (as :meth:`render_di`) and the warp's ``raster`` pass
        (:data:`gicore.buffers.RASTERS`) at ``camera``, in one geometry pass, at the level :meth:`level_for` gives
        a shown pass (level 0 for uploaded uv coordinates): ``"uv"`` (as :meth:`render_uv`) in three more
        render targets; ``"mask"`` (the surface mask) from the DI target's alpha, which every surface writes as
        1; ``None`` (DI alone) an empty dict."""
        self.draw_di_raster(camera, light, raster)
        if raster == "uv":
            passes = self._uv_pass(self._fbos["di_uv"], di=True)
            return passes.pop("di"), passes
        rgba = self._read_many(self._fbos["di"], {"di": (0, 4)})["di"]
        passes = {} if raster is None else {"mask": rgba[..., 3] > 0.0}
        return np.ascontiguousarray(rgba[..., :3]), passes

    def draw_di_raster(self, camera: Camera, light=None, raster: str | None = None) -> dict[str, Any]:
        """:meth:`render_di_raster`'s geometry pass with nothing read back: its targets as textures, for
        shaders that go on from them in this context (the warps' GL backends): ``di`` (RGBA: the DI, alpha 1 on
        every surface, which is the ``"mask"`` pass), and with ``raster="uv"`` also ``uv`` (RG), ``position``
        (RGB) and ``code`` (R: 0 background, 1 an untextured surface, 2 textured). Rows are the image's rows
        (texel row 0 at the top); the textures are redrawn by the next pass."""
        check_raster(raster)
        self._set_light(light)
        uploaded_uv = raster == "uv" and self._uv_projection is None  # coordinates of the full meshes' vertices
        level = 0 if uploaded_uv else self.level_for(camera, shown=True)
        self._draw("di_uv" if raster == "uv" else "di", camera, level)
        uv = {"uv": self._targets[0], "position": self._targets[2], "code": self._targets[3]}
        return {"di": self._targets[4]} | (uv if raster == "uv" else {})

    def render_depth(self, camera: Camera) -> dict[str, np.ndarray]:
        """Linear view depth at pixel centres (HxW, 0 on background; ``gicore.gi_map.texel_depth``) and the
        surface mask (HxW bool): the pixel-level warp's passes."""
        depth = self._read_many(self._draw("depth", camera), {"depth": (0, 1)})["depth"][..., 0]
        return {"depth": depth, "mask": depth > 0}

    def render_gt(self, *args, **kwargs) -> np.ndarray:
        raise NotImplementedError("path-traced GT is not a raster pass: render it with gicore.render.Renderer")

    def render_frame(
        self, camera: Camera, light=None, buffers=DATASET_BUFFERS, spp: int = 64, seed: int = 0, denoise: bool = False
    ) -> dict[str, np.ndarray]:
        """Exactly the named buffers for one frame (see :mod:`gicore.buffers`); ``gt`` is refused."""
        wanted = check_buffer_names(list(buffers))
        if "gt" in wanted:
            raise ValueError("the GL renderer rasterises: 'gt' (path traced) comes from gicore.render (Mitsuba)")
        if set(GBUFFERS) & set(wanted):
            if "di" in wanted:
                out = self.render_di_gbuffers(camera, light, buffers=wanted)
            else:
                out = self._gbuffers(self._draw("gbuffer", camera), wanted)
        else:
            out = {"di": self.render_di(camera, light)}
        return {name: out[name] for name in wanted}
