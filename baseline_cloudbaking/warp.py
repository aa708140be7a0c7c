"""Pixel-level 3D image warping: cloud baking's way to re-use a GI map at another viewpoint (paper V,
Fig. 5(a)). Numpy only.

1. **unproject** (once per GI map, :class:`PointCloud`): every GI-map pixel with a depth becomes a 3D
   point, its centre ray at its linear view depth, kept in homogeneous world coordinates.
2. **project** (per frame): the points go through the target camera's ``M_p · M_v``; points with
   ``w <= near`` are dropped.
3. **splat**: z-buffered forward splatting. Each point covers a square of ``k x k`` target pixels, ``k``
   its footprint: the target/source pixel scale at the point, rounded up, so that neighbouring points'
   squares tile the surface at any magnification (a GI map with a wider FOV than the target, a target
   camera much closer to a surface, a 1° zoom where one texel covers the whole frame). Squares are
   clipped to the frame and only their covered pixels are visited, so the work is the covered area, not
   the footprint's. Nearest point wins: one ``np.minimum.at`` over every covered pixel on a packed 64-bit
   key (float32 depth bits, which order like the depths for positive values, in the high word; the
   source index in the low word).
4. **fill**: holes (target pixels no point reached) are filled by a push-pull pyramid; with a target mask
   (where the target view sees a surface) only there, and the background stays 0.

:class:`PixelWarp` is the :class:`gicore.loop.Warp` of the cloud-baking client: it binds a GI map's
point cloud and, per frame, splats it into the surface mask of the target view (its ``raster`` pass,
rendered with the frame's DI by ``render_di_raster``: on a GL renderer the DI target's alpha, in the same
pass; Mitsuba's centre-sampled :meth:`gicore.render.Renderer.render_uv`).
With identical cameras every point lands on its own pixel with footprint 1: the identity.
"""

from __future__ import annotations

import numpy as np

from gicore.camera import Camera
from gicore.fill import push_pull
from gicore.gi_map import LAYERS, GIMap, Timings
from gicore.loop import HostWarp
from gicore.timing import Stopwatch

#: Footprint bound that only keeps integer coordinates finite: squares are clipped to the frame before
#: any pixel is visited, so even a texel magnified past the whole frame costs only the frame's pixels.
MAX_FOOTPRINT = float(1 << 30)
#: A footprint within this of an integer rounds down (float noise must not turn 1 into 2).
FOOTPRINT_EPS = 1e-3
#: Covered pixels splatted per batch: bounds the temporary index arrays (~40 bytes per pixel).
SPLAT_BATCH = 1 << 21
_EMPTY = np.iinfo(np.uint64).max


class PointCloud:
    """One GI map (``image`` HxWxC seen by ``source`` with linear view ``depth`` HxW, 0 = background) as
    a point cloud, splatted into any target camera by :meth:`splat`."""

    def __init__(self, image: np.ndarray, depth: np.ndarray, source: Camera):
        img = np.asarray(image, dtype=np.float32)
        depth = np.asarray(depth, dtype=np.float32)
        h, w = depth.shape
        if img.ndim != 3 or img.shape[:2] != (h, w) or (h, w) != (source.height, source.width):
            raise ValueError(
                f"image {img.shape} and depth {depth.shape} must both be {source.height}x{source.width} (the "
                "source camera)"
            )
        if not (np.all(np.isfinite(img)) and np.all(np.isfinite(depth))):
            raise ValueError("image or depth contains NaN or Inf")
        src = np.flatnonzero(depth > 0)
        d = depth.ravel()[src].astype(np.float64)
        p = source.proj()
        x_ndc = 2.0 * (src % w + 0.5) / w - 1.0
        y_ndc = 1.0 - 2.0 * (src // w + 0.5) / h
        eye = np.stack([x_ndc * d / p[0, 0], y_ndc * d / p[1, 1], -d, np.ones_like(d)])
        self.points = (np.linalg.inv(source.view()) @ eye).astype(np.float32)  # 4 x N world, homogeneous
        # world size of a source pixel at each point: depth over the focal length in pixels
        self.src_depth_over_focal = (d / (p[0, 0] * w / 2.0)).astype(np.float32)
        self.colours = img.reshape(h * w, -1)[src]
        self.channels = img.shape[2]

    def splat(
        self, target: Camera, target_mask: np.ndarray | None = None, fill: bool = True
    ) -> tuple[np.ndarray, np.ndarray, Timings]:
        """(target-sized image, valid mask, timings). Invalid pixels hold the hole filling (``fill``) or 0;
        outside ``target_mask`` everything is 0 and invalid."""
        th, tw = target.height, target.width
        if target_mask is not None and target_mask.shape != (th, tw):
            raise ValueError(f"target_mask must be {th}x{tw}, got {target_mask.shape}")
        sw = Stopwatch()
        clip = target.view_proj().astype(np.float32) @ self.points
        cw = clip[3]
        front = np.flatnonzero(cw > target.near)
        clip, cw = clip[:, front], cw[front]
        half_w = 0.5 / cw
        col = (clip[0] * half_w + 0.5) * tw
        row = (0.5 - clip[1] * half_w) * th
        # footprint: target pixels per source pixel at this point (world size of a source pixel over the
        # world size of a target pixel at the point's target depth)
        scale = self.src_depth_over_focal[front] * (target.proj()[0, 0] * tw / 2.0) / cw
        k = np.ceil(np.minimum(scale, MAX_FOOTPRINT) - FOOTPRINT_EPS).clip(1.0).astype(np.intp)
        x0 = np.floor(col - 0.5 * k + 0.5).astype(np.intp)
        y0 = np.floor(row - 0.5 * k + 0.5).astype(np.intp)
        sw.lap("project")

        key = (cw.view(np.uint32).astype(np.uint64) << np.uint64(32)) | front.astype(np.uint64)
        zbuf = np.full(th * tw, _EMPTY, dtype=np.uint64)
        _zbuffer(zbuf, key, x0, y0, k, tw, th)
        valid = zbuf != _EMPTY
        if target_mask is not None:
            valid &= target_mask.ravel().astype(bool)
        out = np.zeros((th * tw, self.channels), dtype=np.float32)
        winners = (zbuf[valid] & np.uint64(0xFFFFFFFF)).astype(np.intp)
        out[valid] = self.colours[winners]
        out, valid = out.reshape(th, tw, -1), valid.reshape(th, tw)
        sw.lap("splat")

        if fill:
            out = push_pull(out, valid.astype(np.float32))
            if target_mask is not None:
                out[~target_mask.astype(bool)] = 0.0
        sw.lap("fill")
        return out, valid, sw.ms


def _zbuffer(
    zbuf: np.ndarray, key: np.ndarray, x0: np.ndarray, y0: np.ndarray, k: np.ndarray, tw: int, th: int
) -> None:
    """Keep, per pixel of ``zbuf`` (th*tw), the smallest ``key`` of the squares [x0, x0+k) x [y0, y0+k)
    that cover it, visiting only each square's part inside the frame."""
    xs, ys = np.clip(x0, 0, tw), np.clip(y0, 0, th)
    wide = np.clip(x0 + k, 0, tw) - xs
    high = np.clip(y0 + k, 0, th) - ys
    area = wide * high
    keep = np.flatnonzero(area > 0)
    xs, ys, wide, area, key = xs[keep], ys[keep], wide[keep], area[keep], key[keep]
    ends = np.cumsum(area)
    start = 0
    while start < len(keep):
        # a batch of whole squares covering about SPLAT_BATCH pixels (at least one square)
        stop = max(start + 1, int(np.searchsorted(ends, (ends[start - 1] if start else 0) + SPLAT_BATCH, side="right")))
        first = ends[start - 1] if start else 0
        owner = np.repeat(np.arange(start, stop), area[start:stop])
        offset = np.arange(first, ends[stop - 1]) - (ends[owner] - area[owner])
        dy, dx = np.divmod(offset, wide[owner])
        np.minimum.at(zbuf, (ys[owner] + dy) * tw + xs[owner] + dx, key[owner])
        start = stop


class PixelWarp(HostWarp):
    """Pixel-level warping as the cloud-baking client's :class:`gicore.loop.Warp`: :meth:`bind` unprojects a
    GI map's ``layer`` into a :class:`PointCloud`; :meth:`warp` splats it into the target view's surface mask
    (its ``raster`` pass) and fills the holes on surfaces (push-pull). The current DI is not used."""

    name = "pixel"
    raster = "mask"
    stages = ("bind", "project", "splat", "fill")
    #: Maps come as linear radiance: the host decodes them (:class:`~baseline_cloudbaking.gl_warp.GLPixelWarp`
    #: takes 8-bit display values and decodes them on the GPU).
    takes_display = False

    def __init__(self, layer: str = "radiance"):
        if layer not in LAYERS.values():
            raise ValueError(f"layer must be one of {tuple(LAYERS.values())}, got {layer!r}")
        self.layer = layer
        self.cloud: PointCloud | None = None

    def bind(self, gi: GIMap) -> Timings:
        sw = Stopwatch()
        self.cloud = PointCloud(gi.layer(self.layer), gi.depth, gi.camera)
        sw.lap("bind")
        return sw.ms

    def warp(
        self, camera: Camera, di: np.ndarray, passes: dict[str, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, Timings]:
        if self.cloud is None:
            raise RuntimeError("no GI map is bound; call bind() first")
        mask = passes["mask"]
        out, valid, timings = self.cloud.splat(camera, target_mask=mask)
        return out, valid | ~mask, timings
