"""Mitsuba 3 rendering of scene specs: path-traced GT, direct illumination, G-buffers
(docs/architecture.md, Mitsuba passes).

This is the only module that imports Mitsuba. Its variant, and the denoiser of the GT, are chosen before the
import by :mod:`gicore.mitsuba_variant` (``GIGAN_MITSUBA_VARIANT=auto|cpu|cuda``): ``cuda_ad_rgb`` with
Mitsuba's OptiX denoiser (or OIDN on the GPU) where a CUDA device is present, else ``llvm_ad_rgb`` (libLLVM
>= 16, located before the import; without one the ~45x slower ``scalar_rgb``) with Intel Open Image Denoise.

One :class:`Renderer` holds one compiled scene at one resolution. Cameras, the light and vertex
texture coordinates are updated in place through ``mi.traverse`` (no recompilation). All passes share
one box-filtered film, so G-buffers are unblended per-sample values and a pixel's position projects
back inside that pixel.
"""

from __future__ import annotations

import os
from collections.abc import Collection

import numpy as np

from gicore.buffers import DATASET_BUFFERS, GBUFFERS, check_buffer_names, check_raster
from gicore.camera import Camera
from gicore.error_policy import RESOLUTION_MAX, RESOLUTION_MIN
from gicore.geometry import SceneObject, scene_objects
from gicore.mitsuba_variant import find_libllvm, mitsuba_choice
from gicore.scene import SceneSpec

CHOICE = mitsuba_choice()
VARIANT = CHOICE.variant
if libllvm := find_libllvm():  # beside the CUDA variant too: Dr.Jit must never load an older LLVM of the system
    os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
import drjit as dr  # noqa: E402  (after DRJIT_LIBLLVM_PATH is set)
import mitsuba as mi  # noqa: E402

mi.set_variant(VARIANT)


def set_render_threads(threads: int) -> None:
    """Give every later render of this process ``threads`` Dr.Jit threads (a pool worker's share of the cores)."""
    dr.set_thread_count(threads)


#: Path depth of the ground truth; DI is depth 2 (camera ray + one bounce to the light).
GT_MAX_DEPTH = 12
DI_MAX_DEPTH = 2
GBUFFER_AOVS = "albedo:albedo,normal:sh_normal,position:position,dist:depth"


def _mesh_to_mitsuba(obj: SceneObject) -> mi.Mesh:
    bsdf: dict = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(obj.albedo)}}
    if obj.roughness is not None:
        bsdf = {
            "type": "roughplastic",
            "distribution": "ggx",
            "alpha": obj.roughness,
            "int_ior": 1.45,
            "diffuse_reflectance": {"type": "rgb", "value": list(obj.albedo)},
        }
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = obj.mesh
    m = mi.Mesh(
        obj.name,
        len(mesh.vertices),
        len(mesh.faces),
        props=props,
        has_vertex_normals=obj.roughness is not None,
        has_vertex_texcoords=True,
    )
    params = mi.traverse(m)
    params["vertex_positions"] = mi.Float(mesh.vertices.ravel())
    params["faces"] = mi.UInt32(mesh.faces.astype(np.uint32).ravel())
    if obj.roughness is not None:  # smooth shading for curved anatomy; flat quads need none
        params["vertex_normals"] = mi.Float(mesh.vertex_normals().ravel())
    params["vertex_texcoords"] = mi.Float(np.zeros(2 * len(mesh.vertices), dtype=np.float32))
    params.update()
    return m


class Renderer:
    """Renders one scene spec at a fixed square ``resolution``.

    Every render call takes the camera (and light) explicitly; the renderer moves Mitsuba's sensor and
    emitter to them first. Outputs are float32 HxWxC numpy arrays of linear values.
    """

    def __init__(self, spec: SceneSpec, resolution: int | None = None):
        self.spec = spec
        self.resolution = spec.resolution if resolution is None else int(resolution)
        if not RESOLUTION_MIN <= self.resolution <= RESOLUTION_MAX:  # 0 must not mean "the spec's"
            raise ValueError(f"resolution must be an integer in [{RESOLUTION_MIN}, {RESOLUTION_MAX}], got {resolution}")
        self.objects = scene_objects(spec)
        scene: dict = {
            "type": "scene",
            "sensor": {
                "type": "perspective",
                "fov_axis": "x",
                "fov": spec.camera.gi_fov,
                "film": {
                    "type": "hdrfilm",
                    "width": self.resolution,
                    "height": self.resolution,
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
            },
        }
        for obj in self.objects:
            scene[obj.name] = _mesh_to_mitsuba(obj)
        light = spec.light
        if light.size > 0:
            area = light.size**2
            scene["light"] = {
                "type": "rectangle",
                "to_world": self._area_light_transform(light.position),
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": light.intensity / area}},
            }
        else:
            scene["light"] = {
                "type": "point",
                "position": list(light.position),
                "intensity": {"type": "rgb", "value": light.intensity},
            }
        self.scene = mi.load_dict(scene)
        self.params = mi.traverse(self.scene)
        self._integrators = {
            "gt": mi.load_dict({"type": "path", "max_depth": GT_MAX_DEPTH}),
            "di": mi.load_dict({"type": "path", "max_depth": DI_MAX_DEPTH}),
            "aov": mi.load_dict({"type": "aov", "aovs": GBUFFER_AOVS}),
            # The warp pass (render_uv): interpolated texcoords, world position and shape id in one render.
            "uv": mi.load_dict({"type": "aov", "aovs": "uv:uv,pos:position,shape:shape_index"}),
        }
        self._camera: Camera | None = None
        self._light: tuple[float, float, float] = tuple(light.position)

    # -- state updates ---------------------------------------------------------------------------
    def _area_light_transform(self, position) -> mi.ScalarTransform4f:
        s = self.spec.light.size / 2.0
        return mi.ScalarTransform4f().translate(list(position)).rotate([1, 0, 0], 90).scale([s, s, 1.0])

    def _set_camera(self, camera: Camera) -> None:
        if (camera.width, camera.height) != (self.resolution, self.resolution):
            raise ValueError(
                f"camera is {camera.width}x{camera.height} but this renderer renders "
                f"{self.resolution}x{self.resolution}"
            )
        if camera == self._camera:
            return
        self.params["sensor.to_world"] = mi.ScalarTransform4f(camera.to_world().tolist())
        self.params["sensor.x_fov"] = camera.fov
        self.params["sensor.near_clip"] = camera.near
        self.params["sensor.far_clip"] = camera.far
        self.params.update()
        self._camera = camera

    def _set_light(self, position: tuple[float, float, float] | None) -> None:
        """Move the light; ``None`` means the spec's rest position (never "wherever it was last")."""
        position = tuple(self.spec.light.position) if position is None else tuple(position)
        if position == self._light:
            return
        if not np.all(np.isfinite(position)):
            raise ValueError(f"light position must be finite, got {position}")
        if self.spec.light.size > 0:
            self.params["light.to_world"] = self._area_light_transform(position)
        else:
            self.params["light.position"] = mi.ScalarPoint3f(list(position))
        self.params.update()
        self._light = tuple(position)

    def set_texcoords(self, name: str, uv: np.ndarray) -> None:
        """Replace the per-vertex texture coordinates of object ``name`` (N x 2); no BVH rebuild."""
        key = f"{name}.vertex_texcoords"
        if key not in self.params:
            raise KeyError(f"no object {name!r}; objects: {[o.name for o in self.objects]}")
        uv = np.ascontiguousarray(uv, dtype=np.float32)
        if uv.shape != (len(self.params[f"{name}.vertex_positions"]) // 3, 2):
            raise ValueError(f"texcoords for {name!r} must be (n_vertices, 2), got {uv.shape}")
        self.params[key] = mi.Float(uv.ravel())
        self.params.update()

    # -- passes ----------------------------------------------------------------------------------
    def _render(self, integrator: str, spp: int, seed: int) -> np.ndarray:
        if spp < 1:
            raise ValueError(f"spp must be >= 1, got {spp}")
        img = mi.render(self.scene, integrator=self._integrators[integrator], spp=spp, seed=seed)
        return np.array(img, dtype=np.float32)

    def render_gt(
        self, camera: Camera, light=None, spp: int = 64, seed: int = 0, max_depth: int | None = None
    ) -> np.ndarray:
        """Path-traced global illumination (max depth ``GT_MAX_DEPTH`` unless given)."""
        self._set_camera(camera)
        self._set_light(light)
        if max_depth is None:
            return self._render("gt", spp, seed)
        self._integrators["custom"] = mi.load_dict({"type": "path", "max_depth": max_depth})
        return self._render("custom", spp, seed)

    def render_di(self, camera: Camera, light=None, spp: int = 1, seed: int = 0) -> np.ndarray:
        """Direct illumination: emitted light plus one bounce (diffuse + glossy) with shadow rays."""
        self._set_camera(camera)
        self._set_light(light)
        return self._render("di", spp, seed)

    def render_di_raster(
        self, camera: Camera, light=None, raster: str | None = None, seed: int = 0
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """A shown frame's DI (1 spp) and the warp's ``raster`` pass (:data:`gicore.buffers.RASTERS`) at
        ``camera``: :meth:`render_uv`'s outputs for ``"uv"``, its ``mask`` alone for ``"mask"``, nothing for
        None. Two passes here (a ray tracer has no render targets to share); one on the GL renderer."""
        check_raster(raster)
        di = self.render_di(camera, light, seed=seed)
        if raster is None:
            return di, {}
        passes = self.render_uv(camera)
        return di, passes if raster == "uv" else {"mask": passes["mask"]}

    def render_indirect(self, camera: Camera, light=None, spp: int = 64, seed: int = 0) -> np.ndarray:
        """Indirect-only light: GT minus DI with the same seed and spp, so the shared first bounce
        cancels sample for sample and the result is non-negative (up to float rounding)."""
        gt = self.render_gt(camera, light, spp, seed)
        di = self._render("di", spp, seed)
        return gt - di

    def render_gbuffers(self, camera: Camera, seed: int = 0, centre: bool = False) -> dict[str, np.ndarray]:
        """Albedo, view-space normal (GL), linear view depth, world position and hit mask (1 spp).

        ``centre``: sample each pixel at its centre, as a rasteriser does (and :meth:`render_uv`), instead of
        at a jittered point: the depth is then exactly the one the warps need at texel centres."""
        if not centre:
            self._set_camera(camera)
            return self._split_gbuffers(camera, self._render("aov", 1, seed))
        img = mi.render(
            self.scene, sensor=self._centre_sensor_at(camera), integrator=self._integrators["aov"], spp=1, seed=seed
        )
        return self._split_gbuffers(camera, np.array(img, dtype=np.float32))

    def render_di_gbuffers(
        self, camera: Camera, light=None, seed: int = 0, centre: bool = False, buffers: Collection[str] = GBUFFERS
    ) -> dict[str, np.ndarray]:
        """DI (1 spp) and the G-buffers of :meth:`render_gbuffers` that ``buffers`` names (other names are
        ignored): what a client renders per frame.

        Two passes: an AOV integrator nesting the DI path tracer gives the same pixels in one pass but
        was measured slower (``bench render``: 21 ms vs 7.2 + 8.4 ms on lung_plane at 256²)."""
        di = self.render_di(camera, light, spp=1, seed=seed)
        gbuffers = self.render_gbuffers(camera, seed, centre)
        return {"di": di} | {name: gbuffers[name] for name in buffers if name in gbuffers}

    @staticmethod
    def _split_gbuffers(camera: Camera, img: np.ndarray) -> dict[str, np.ndarray]:
        albedo, normal_w, position, dist = img[..., 0:3], img[..., 3:6], img[..., 6:9], img[..., 9:10]
        mask = (dist > 0).astype(np.float32)
        view = camera.view()
        normal_v = normal_w @ view[:3, :3].T * mask
        # Mitsuba's depth AOV is distance along the ray; the networks want linear view depth (view z).
        depth = camera.view_depth(position)[..., None].astype(np.float32) * mask
        return {
            "albedo": albedo * mask,
            "normal": normal_v.astype(np.float32),
            "depth": depth,
            "position": position * mask,
            "mask": mask,
        }

    def render_uv(self, camera: Camera) -> dict[str, np.ndarray]:
        """One AOV pass sampled exactly at pixel centres, for warping at ``camera``.

        Returns ``uv`` (HxWx2): the vertex texture coordinates (see :meth:`set_texcoords`) interpolated
        with the hit's barycentrics, i.e. affinely in world position over each triangle; ``position``
        (HxWx3): world position (0 on background); ``mask`` (HxW bool): a surface was hit; ``textured``
        (HxW bool): the hit surface is a scene object, whose texcoords :meth:`set_texcoords` controls (an
        area light's quad is not).

        Unlike the other passes it does not jitter samples inside the pixel: a pixel's position is the
        hit of its centre ray (it projects back onto the centre, up to float rounding), so warping a GI
        map to its own camera reads each texel at its centre and is the identity. Deterministic.
        """
        img = np.array(
            mi.render(self.scene, sensor=self._centre_sensor_at(camera), integrator=self._integrators["uv"], spp=1),
            dtype=np.float32,
        )
        shape = img[..., 5].astype(np.int64)
        # contiguous copies: per-pixel gathers from them are several times faster than from strided views
        uv, position = np.ascontiguousarray(img[..., 0:2]), np.ascontiguousarray(img[..., 2:5])
        return {"uv": uv, "position": position, "mask": shape > 0, "textured": np.isin(shape, self._object_shape_ids)}

    def _centre_sensor_at(self, camera: Camera) -> mi.Sensor:
        """The sensor that samples pixel centres (1 spp, unjittered), moved to ``camera``."""
        import drjit as dr

        self._set_camera(camera)  # validates the resolution
        if getattr(self, "_centre_sensor", None) is None:
            film = {
                "type": "hdrfilm",
                "width": self.resolution,
                "height": self.resolution,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            }
            sampler = {"type": "stratified", "sample_count": 1, "jitter": False}  # 1 spp, unjittered: the pixel centre
            self._centre_sensor = mi.load_dict(
                {"type": "perspective", "fov_axis": "x", "fov": camera.fov, "film": film, "sampler": sampler}
            )
            self._centre_params = mi.traverse(self._centre_sensor)
            self._centre_camera: Camera | None = None
            names = {o.name for o in self.objects}
            # shape_index AOV values are Dr.Jit registry ids of the hit shape's pointer (0 = no hit)
            self._object_shape_ids = np.array(
                [dr.reinterpret_array(mi.UInt32, mi.ShapePtr(s))[0] for s in self.scene.shapes() if s.id() in names]
            )
        if camera != self._centre_camera:
            p = self._centre_params
            p["to_world"] = mi.ScalarTransform4f(camera.to_world().tolist())
            p["x_fov"], p["near_clip"], p["far_clip"] = camera.fov, camera.near, camera.far
            p.update()
            self._centre_camera = camera
        return self._centre_sensor

    def denoise(self, color: np.ndarray, gbuffers: dict[str, np.ndarray]) -> np.ndarray:
        """The HDR ``color`` denoised with albedo and normal guides by the variant's denoiser: Intel Open Image
        Denoise on the CPU variants, Mitsuba's OptiX denoiser on the CUDA one (OIDN on the CUDA device where the
        driver lacks OptiX's weights; the copies to and from the device are part of the denoise)."""
        color, albedo = np.ascontiguousarray(color), np.ascontiguousarray(gbuffers["albedo"])
        if CHOICE.denoiser == "optix":
            if getattr(self, "_optix", None) is None:
                self._optix = mi.OptixDenoiser([self.resolution, self.resolution], albedo=True, normals=True)
            # the G-buffer normals are OpenGL view-space (x right, z back); Mitsuba's sensor frame has x left,
            # z forward, and its denoiser turns that frame into OptiX's (which is OpenGL's) itself
            normal = np.ascontiguousarray(gbuffers["normal"] * np.float32([-1.0, 1.0, -1.0]))
            out = self._optix(mi.TensorXf(color), albedo=mi.TensorXf(albedo), normals=mi.TensorXf(normal))
            return np.array(out, dtype=np.float32)
        import pyoidn

        normal = np.ascontiguousarray(gbuffers["normal"])
        if CHOICE.denoiser == "oidn-cuda":
            import torch

            on_gpu = [torch.from_numpy(a).cuda() for a in (color, albedo, normal)]
            return pyoidn.denoise(*on_gpu, hdr=True).cpu().numpy()
        return pyoidn.denoise(color, albedo, normal, hdr=True)

    def render_frame(
        self, camera: Camera, light=None, buffers=DATASET_BUFFERS, spp: int = 64, seed: int = 0, denoise: bool = False
    ) -> dict[str, np.ndarray]:
        """Render exactly the named buffers for one frame (see :mod:`gicore.buffers`)."""
        wanted = check_buffer_names(list(buffers))
        needs_gbuffers = bool(set(GBUFFERS) & set(wanted)) or (denoise and "gt" in wanted)
        if needs_gbuffers and "di" in wanted:
            out = gb = self.render_di_gbuffers(camera, light, seed)
        else:
            gb = self.render_gbuffers(camera, seed) if needs_gbuffers else {}
            out = {"di": self.render_di(camera, light, spp=1, seed=seed)} if "di" in wanted else {}
        if "gt" in wanted:
            gt = self.render_gt(camera, light, spp=spp, seed=seed)
            out = out | {"gt": self.denoise(gt, gb) if denoise else gt}
        return {name: out[name] if name in out else gb[name] for name in wanted}
