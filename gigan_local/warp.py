"""Structure-aware 3D image warping (paper V, Algorithm 1, eq. 5): GIGAN's way to re-use a GI map at
another viewpoint.

The GI map becomes a projective texture on the scene's own triangles: **bind** (per map: each vertex's
GI-camera clip coordinates become its texture coordinates), **raster** (per frame: interpolated in the frame's
DI pass), **project** (per pixel: ``uv = clip.xy / (2 w) + 0.5``), **depth test + lookup** (bilinear, each tap
depth-tested with a slope-scaled bias, so colour never bleeds across a depth edge) and **fill** (invalid pixels:
this frame's DI plus the map's coarse indirect light). Clip coordinates are interpolated rather than eq. 5's
per-vertex uv because they are affine in world position: exact inside large triangles, and a point behind the
GI camera is simply invalid, never inf or NaN. The reasoning in full: docs/architecture.md, Structure-aware
warping.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gicore.camera import Camera
from gicore.fill import push_pull
from gicore.gi_map import LAYERS, GIMap, Timings
from gicore.loop import HostWarp
from gicore.timing import Stopwatch

if TYPE_CHECKING:
    from gicore.render import Renderer

#: Relative depth tolerance of the occlusion test (see the module docstring).
DEPTH_REL_TOL = 0.02
#: Sub-texel precision of bilinear filtering: weights are rounded to 1/256 as GPU texture units do. It
#: makes a lookup at a texel centre (up to float32 rounding of the interpolated coordinates) read that
#: texel exactly, so warping a GI map to its own camera is the identity.
SUBTEXEL = 256.0
#: Size (texels across) of the coarse mip level that invalid pixels read their indirect light from.
FALLBACK_TEXELS = 32


def clip_xy(camera: Camera, points: np.ndarray) -> np.ndarray:
    """Clip coordinates x, y (..., 2) of world points (..., 3) under ``camera``'s M_p · M_v (eq. 5 before
    the divide by w, which the per-pixel projection does)."""
    vp = camera.view_proj()[:2]
    return np.asarray(points, dtype=np.float64) @ vp[:, :3].T + vp[:, 3]


def bind_coordinates(renderer: Renderer, camera: Camera) -> None:
    """Eq. 5 per vertex: every object's ``camera`` clip (x, y) as its texture coordinates. A renderer that
    projects them in its vertex shader (:meth:`gicore.gl.GLRenderer.set_texcoord_projection`, as WebGL would) is
    given the camera; on the others (Mitsuba) they are computed here and uploaded."""
    project = getattr(renderer, "set_texcoord_projection", None)
    if project is not None:
        project(camera)
    else:
        for obj in renderer.objects:
            renderer.set_texcoords(obj.name, clip_xy(camera, obj.mesh.vertices))


def depth_slack(depth: np.ndarray) -> np.ndarray:
    """Per-texel depth change to the next texel, summed over x and y (HxW), the smaller side of each.

    Background texels (depth 0) and their neighbours contribute 0: a jump to the background is an edge,
    not a slope; so does the frame's border (the texel beyond it counts as the texel itself).
    """
    d = np.asarray(depth, dtype=np.float32)
    hit = d > 0
    # + inf to a step whose far texel is background leaves it out of the minimum (and adds nothing else)
    far = np.where(hit, np.float32(0.0), np.float32(np.inf))
    slack = np.zeros_like(d)
    for axis in (1, 0):
        dv, fv = np.moveaxis(d, axis, 0), np.moveaxis(far, axis, 0)  # neighbours along ``axis``: consecutive rows
        steps = np.abs(np.diff(dv, axis=0))  # |d[i+1] - d[i]|
        step = np.minimum(steps[:-1] + fv[:-2], steps[1:] + fv[2:])  # to the previous texel, to the next
        step[step == np.inf] = 0.0  # both neighbours background: no slope
        np.moveaxis(slack, axis, 0)[1:-1] += step
    slack *= hit
    return slack


@dataclass(frozen=True)
class GITexture:
    """A GI map prepared for lookups, built once per GI map (:meth:`build`).

    ``camera``: the GI camera; ``image``: the map, HxWxC (any channels); ``depth``: the GI camera's linear
    view depth at texel centres (HxW, 0 = background). Precomputed for the per-frame lookups: ``planes``
    ((2 + C) x H*W, contiguous), one plane per quantity gathered: each texel's depth minus and plus its
    slack (``+inf``/``-inf`` on background, so the depth test always fails there), then the C channels;
    ``coarse`` (h x w x C), the fallback's mip level with ``coarse_step`` texels per coarse texel, and
    ``mean`` (C), the fallback behind the GI camera.
    """

    camera: Camera
    image: np.ndarray
    depth: np.ndarray
    planes: np.ndarray
    coarse: np.ndarray
    coarse_step: int
    mean: np.ndarray

    @classmethod
    def build(
        cls, camera: Camera, image: np.ndarray, depth: np.ndarray, indirect: np.ndarray | None = None
    ) -> GITexture:
        """``indirect`` (HxWxC, default ``image``) is what the fallback extrapolates: the GI map's
        indirect light when ``image`` is a full GI map that invalid pixels add to their current DI."""
        image, depth, indirect = checked_map(camera, image, depth, indirect)
        slack = depth_slack(depth)
        hit = depth > 0
        planes = np.empty((2 + image.shape[2], depth.size), dtype=np.float32)
        np.copyto(planes[0], np.where(hit, depth - slack, np.inf).ravel())
        np.copyto(planes[1], np.where(hit, depth + slack, -np.inf).ravel())
        planes[2:] = image.reshape(depth.size, -1).T
        coarse, step, mean = fallback_level(indirect, hit)
        return cls(camera, image, depth, planes, coarse, step, mean)


def checked_map(
    camera: Camera, image: np.ndarray, depth: np.ndarray, indirect: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``image``, ``depth`` and ``indirect`` (default ``image``) as float32 arrays, checked against each other and
    ``camera``: a shape that does not fit, a NaN or an Inf is a ValueError."""
    image = np.asarray(image, dtype=np.float32)
    depth = np.asarray(depth, dtype=np.float32)
    indirect = image if indirect is None else np.asarray(indirect, dtype=np.float32)
    if image.ndim != 3 or image.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"GI map must be {camera.height}x{camera.width}xC for its camera, got {image.shape}")
    if depth.shape != image.shape[:2] or indirect.shape != image.shape:
        raise ValueError(
            f"GI depth must be {image.shape[:2]} and indirect {image.shape}, got {depth.shape} and {indirect.shape}"
        )
    if not (np.all(np.isfinite(image)) and np.all(np.isfinite(depth)) and np.all(np.isfinite(indirect))):
        raise ValueError("GI map, GI depth or indirect map contains NaN or Inf")
    return image, depth, indirect


def fallback_level(indirect: np.ndarray, hit: np.ndarray) -> tuple[np.ndarray, int, np.ndarray]:
    """The fallback's coarse level of ``indirect`` over the ``hit`` texels (about :data:`FALLBACK_TEXELS` across),
    its texels per coarse texel, and the mean over all hit texels (:attr:`GITexture.coarse` and the rest)."""
    step = fallback_step(*indirect.shape[:2])
    coarse, mean = _coarse_level(indirect, hit, step)
    return coarse, step, mean


def fallback_step(height: int, width: int) -> int:
    """GI texels per texel of the fallback's coarse level of a ``height`` x ``width`` map."""
    return max(1, -(-max(height, width) // FALLBACK_TEXELS))


def _blocks(x: np.ndarray, step: int) -> np.ndarray:
    """``x`` (h x w x ...) as (h/step, step, w/step, step, ...) blocks, zero-padded at the far edges."""
    h, w = x.shape[:2]
    hb, wb = -(-h // step), -(-w // step)
    if h % step or w % step:
        x = np.pad(x, ((0, hb * step - h), (0, wb * step - w)) + ((0, 0),) * (x.ndim - 2))
    return x.reshape(hb, step, wb, step, *x.shape[2:])


def _coarse_level(image: np.ndarray, hit: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Averages of ``image`` over the ``hit`` texels of ``step`` x ``step`` blocks (blocks without any
    hit filled from their neighbours), and the mean over all hit texels (0 without any)."""
    weight = _blocks(hit.astype(np.float32), step)
    # one contraction weights and sums each block (no weighted copy of the image): it runs each GI map
    csum = np.einsum("iajbc,iajb->ijc", _blocks(image, step), weight, optimize=True)
    wsum = weight.sum(axis=(1, 3))
    mean = csum.sum(axis=(0, 1)) / max(float(wsum.sum()), 1.0)
    return push_pull(csum / np.maximum(wsum, 1.0)[..., None], np.minimum(wsum, 1.0)), mean.astype(np.float32)


def checked_options(layer: str, depth_rel_tol: float) -> tuple[str, float]:
    """A structure-aware warp's ``layer`` (one of :data:`gicore.gi_map.LAYERS`) and ``depth_rel_tol`` (>= 0),
    checked: anything else is a ValueError."""
    if layer not in LAYERS.values():
        raise ValueError(f"layer must be one of {tuple(LAYERS.values())}, got {layer!r}")
    if not depth_rel_tol >= 0.0:
        raise ValueError(f"depth_rel_tol must be >= 0, got {depth_rel_tol}")
    return layer, float(depth_rel_tol)


class StructureAwareWarp(HostWarp):
    """Algorithm 1 on one renderer, as a :class:`gicore.loop.Warp`: :meth:`bind` a GI map once, then
    :meth:`warp` it to every frame.

    ``layer`` is what is warped (:data:`gicore.gi_map.LAYERS`): the map itself (``radiance``, eq. 1), whose
    invalid pixels get the current DI plus the coarse indirect light, or its indirect part (``indirect``,
    the residual composition), whose invalid pixels get the coarse indirect light alone. Binding changes
    the renderer's vertex texture coordinates, so one renderer serves one bound GI map at a time.
    """

    name = "structure"
    raster = "uv"
    stages = ("bind", "project", "depth_test", "lookup", "fill")

    def __init__(self, renderer: Renderer, layer: str = "radiance", depth_rel_tol: float = DEPTH_REL_TOL):
        self.renderer = renderer
        self.layer, self.depth_rel_tol = checked_options(layer, depth_rel_tol)
        self.texture: GITexture | None = None
        self._w_row = np.zeros(4, dtype=np.float32)

    def bind(self, gi: GIMap) -> Timings:
        """Per GI map: the lookup texture of the map's ``layer`` (with its indirect light for the fallback),
        and eq. 5 per vertex (:meth:`bind_texture`)."""
        sw = Stopwatch()
        self.bind_texture(GITexture.build(gi.camera, gi.layer(self.layer), gi.depth, gi.indirect))
        sw.lap("bind")
        return sw.ms

    def bind_texture(self, texture: GITexture) -> None:
        """``texture`` as the bound map, its GI camera's coordinates bound per vertex (:func:`bind_coordinates`)."""
        bind_coordinates(self.renderer, texture.camera)
        self.texture = texture
        self._w_row = texture.camera.view_proj()[3].astype(np.float32)  # clip w = this row . (p, 1)

    def warp(
        self, camera: Camera, di: np.ndarray, passes: dict[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, Timings]:
        """The bound layer at ``camera`` (see :class:`gicore.loop.Warp`) from its uv pass ``passes``
        (:meth:`resample`); background counts as valid."""
        out, valid, timings = self.resample(passes, base=di if self.layer == "radiance" else None)
        return out, valid | ~passes["mask"], timings

    def texel_coords(self, uv_pass: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Continuous GI-map pixel coordinates (col, row) (HxWx2, texel centres at +0.5) and GI-camera w
        (HxW) of every pixel of a uv pass (``render_uv`` after :meth:`bind`); both 0 where ``w <= near`` or
        no textured surface was hit."""
        idx, x, y, w, front = self._project(uv_pass)
        h, wd = uv_pass["mask"].shape
        coords = np.zeros((h * wd, 2))
        ws = np.zeros(h * wd)
        idx = idx[front]
        coords[idx, 0], coords[idx, 1], ws[idx] = x[front] + 0.5, y[front] + 0.5, w[front]
        return coords.reshape(h, wd, 2), ws.reshape(h, wd)

    def coordinate_errors(self, camera: Camera) -> dict[str, np.ndarray]:
        """|interpolated - per-pixel projected| GI-map coordinates (px) at ``camera``, on pixels in front of the
        bound GI camera and inside its map: for the bound clip coordinates, and for eq. 5's per-vertex uv
        interpolated as is (undefined where w <= 0), the alternative the module docstring sets aside. The
        bound coordinates are restored afterwards."""
        gi_cam, renderer = self._bound().camera, self.renderer
        uv_pass = renderer.render_uv(camera)
        coords, _ = self.texel_coords(uv_pass)
        ref, w = gi_cam.project_pixels(uv_pass["position"].astype(np.float64))
        inside = uv_pass["textured"] & (w > gi_cam.near) & np.all((ref >= 0) & (ref <= gi_cam.width), axis=-1)
        out = {"homogeneous clip (ours)": np.abs(coords - ref)[inside].max(axis=-1)}
        for obj in renderer.objects:
            renderer.set_texcoords(obj.name, gi_cam.project_uv(obj.mesh.vertices)[0])
        naive = renderer.render_uv(camera)["uv"].astype(np.float64)
        naive_px = np.stack([naive[..., 0] * gi_cam.width, (1.0 - naive[..., 1]) * gi_cam.height], axis=-1)
        out["per-vertex uv (eq. 5)"] = np.abs(naive_px - ref)[inside].max(axis=-1)
        self.bind_texture(self._bound())
        return out

    def _bound(self) -> GITexture:
        if self.texture is None:
            raise RuntimeError("no GI map is bound; call bind() first")
        return self.texture

    def _project(self, uv_pass: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
        """Flat indices of textured pixels; their texel coordinates x, y (texel centres at integers), w,
        and whether they lie in front of the GI camera (elsewhere x, y are finite but meaningless)."""
        cam = self._bound().camera
        idx = np.flatnonzero(uv_pass["textured"])
        clip = np.take(uv_pass["uv"].reshape(-1, 2), idx, axis=0)
        p = np.take(uv_pass["position"].reshape(-1, 3), idx, axis=0)
        a = self._w_row
        # w exactly from the position rendered in the same pass (GL clip w = GI-camera view depth)
        w = p[:, 0] * a[0] + p[:, 1] * a[1] + p[:, 2] * a[2] + a[3]
        front = w > cam.near
        half_w = 0.5 / np.where(front, w, 1.0)
        x = (clip[:, 0] * half_w + 0.5) * cam.width - 0.5
        y = (0.5 - clip[:, 1] * half_w) * cam.height - 0.5
        return idx, x, y, w, front

    def resample(
        self, uv_pass: dict[str, np.ndarray], base: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, Timings]:
        """The bound GI map seen from the camera of ``uv_pass``: (HxWxC image, HxW valid mask, timings).

        ``uv_pass`` (``render_uv``) must be rendered after :meth:`bind`: it carries the bound coordinates.
        Invalid surface pixels get the fallback (module docstring): ``base`` (the current DI, when the map is
        a full GI map; omit it for an indirect-only map) plus the coarse indirect light. Background is 0.
        """
        tex = self._bound()
        h, wd = uv_pass["mask"].shape
        th, tw = tex.depth.shape
        n_channels = len(tex.planes) - 2
        if base is not None and base.shape != (h, wd, n_channels):
            raise ValueError(f"base must be {h}x{wd}x{n_channels}, got {base.shape}")
        if base is not None and not np.all(np.isfinite(base)):
            raise ValueError("base (the current DI) contains NaN or Inf; check the render that produced it")
        sw = Stopwatch()
        idx, x, y, w, front = self._project(uv_pass)
        ok = front & (x >= -0.5) & (x <= tw - 0.5) & (y >= -0.5) & (y <= th - 0.5)  # uv in [0, 1]
        np.clip(x, 0.0, tw - 1, out=x)  # clamp to edge (the fallback reads the clamped uv too)
        np.clip(y, 0.0, th - 1, out=y)
        sw.lap("project")

        x0, y0 = np.floor(x), np.floor(y)
        fx = np.rint((x - x0) * SUBTEXEL) * (1.0 / SUBTEXEL)
        fy = np.rint((y - y0) * SUBTEXEL) * (1.0 / SUBTEXEL)
        xa, ra = x0.astype(np.intp), y0.astype(np.intp) * tw
        xb, rb = np.minimum(xa + 1, tw - 1), np.minimum(ra + tw, (th - 1) * tw)
        taps = np.stack([ra + xa, ra + xb, rb + xa, rb + xb])
        gx, gy = 1.0 - fx, 1.0 - fy
        weights = np.stack([gx * gy, fx * gy, gx * fy, fx * fy])
        # |d - w| <= tol * w + slack, written on the precomputed [d - slack, d + slack]
        weights *= (tex.planes[0].take(taps) <= w * (1.0 + self.depth_rel_tol)) & (
            tex.planes[1].take(taps) >= w * (1.0 - self.depth_rel_tol)
        )
        total = weights.sum(axis=0)
        ok &= total > 0.0
        weights /= np.where(ok, total, 1.0)  # rejected taps drop out; invalid pixels get weight 0
        sw.lap("depth_test")

        out = np.zeros((h * wd, n_channels), dtype=np.float32)
        for c, plane in enumerate(tex.planes[2:]):
            out[idx, c] = (plane.take(taps) * weights).sum(axis=0)
        valid = np.zeros(h * wd, dtype=bool)
        valid[idx] = ok
        sw.lap("lookup")

        bad = np.flatnonzero(~ok)
        fallback = self._coarse(tex, x[bad], y[bad])
        fallback[~front[bad]] = tex.mean  # behind the GI camera uv is undefined
        invalid = np.concatenate(
            [idx[bad], np.flatnonzero(uv_pass["mask"] & ~uv_pass["textured"])]
        )  # + e.g. an area light
        fallback = np.concatenate([fallback, np.broadcast_to(tex.mean, (len(invalid) - len(bad), n_channels))])
        if base is not None:
            fallback += np.take(base.reshape(-1, n_channels), invalid, axis=0)
        out[invalid] = fallback
        sw.lap("fill")
        return out.reshape(h, wd, -1), valid.reshape(h, wd), sw.ms

    @staticmethod
    def _coarse(tex: GITexture, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear lookup (N x C) of the coarse fallback level at texel coordinates x, y."""
        ch, cw, n_channels = tex.coarse.shape
        cx = np.clip((x + 0.5) * (1.0 / tex.coarse_step) - 0.5, 0.0, cw - 1)
        cy = np.clip((y + 0.5) * (1.0 / tex.coarse_step) - 0.5, 0.0, ch - 1)
        x0, y0 = np.floor(cx), np.floor(cy)
        fx, fy = cx - x0, cy - y0
        xa, ra = x0.astype(np.intp), y0.astype(np.intp) * cw
        xb, rb = np.minimum(xa + 1, cw - 1), np.minimum(ra + cw, (ch - 1) * cw)
        flat = tex.coarse.reshape(-1, n_channels)
        out = np.take(flat, ra + xa, axis=0) * ((1 - fx) * (1 - fy))[:, None]
        for taps, weight in ((ra + xb, fx * (1 - fy)), (rb + xa, (1 - fx) * fy), (rb + xb, fx * fy)):
            out += np.take(flat, taps, axis=0) * weight[:, None]
        return out
