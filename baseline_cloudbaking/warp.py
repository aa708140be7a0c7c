"""Pixel-level 3D image warping: cloud baking's way to re-use a GI map at another viewpoint (paper V,
Fig. 5(a)). Numpy only.

1. **unproject** (once per GI map, :meth:`PixelWarp.bind`): every GI-map pixel with a depth becomes a 3D
   point, its centre ray at its linear view depth, kept in homogeneous world coordinates.
2. **project** (per frame): the points go through the target camera's ``M_p · M_v``; points with
   ``w <= near`` are dropped.
3. **splat**: z-buffered forward splatting. Each point covers a square of ``k x k`` target pixels, ``k``
   its footprint (target/source pixel scale, ``ceil`` of it, at most ``MAX_FOOTPRINT``), so a GI map with
   a wider FOV than the target does not leave a crack between every other pixel. Nearest point wins:
   one ``np.minimum.at`` per footprint offset on a packed 64-bit key (float32 depth bits, which order like
   the depths for positive values, in the high word; the source index in the low word).
4. **fill**: holes (target pixels no point reached) are filled by a push-pull pyramid; with a target mask
   (where the target view sees a surface, known from the client's own DI render) only there, and the
   background stays 0.

Returns the warped image, the valid mask (pixels that received a splat) and per-stage timings (ms).
With identical cameras every point lands on its own pixel with footprint 1: the identity.
"""

from __future__ import annotations

import time

import numpy as np

from gicore.camera import Camera
from gicore.fill import push_pull

#: Largest splat side in pixels (points closer to the target camera than to the GI camera grow).
MAX_FOOTPRINT = 4
#: A footprint within this of an integer rounds down (float noise must not turn 1 into 2).
FOOTPRINT_EPS = 1e-3
_EMPTY = np.iinfo(np.uint64).max

Timings = dict[str, float]


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


class PixelWarp:
    """One GI map (``image`` HxWxC seen by ``source`` with linear view ``depth`` HxW, 0 = background) as
    a point cloud, warped to any target camera by :meth:`warp`."""

    def __init__(self, image: np.ndarray, depth: np.ndarray, source: Camera):
        img = np.asarray(image, dtype=np.float32)
        depth = np.asarray(depth, dtype=np.float32)
        h, w = depth.shape
        if img.ndim != 3 or img.shape[:2] != (h, w) or (h, w) != (source.height, source.width):
            raise ValueError(f"image {img.shape} and depth {depth.shape} must both be {source.height}x{source.width} (the source camera)")
        if not (np.all(np.isfinite(img)) and np.all(np.isfinite(depth))):
            raise ValueError("image or depth contains NaN or Inf")
        t0 = time.perf_counter()
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
        self.bind_ms = _ms(t0)

    def warp(self, target: Camera, target_mask: np.ndarray | None = None, fill: bool = True) -> tuple[np.ndarray, np.ndarray, Timings]:
        """(target-sized image, valid mask, timings). Invalid pixels hold the hole filling (``fill``) or 0;
        outside ``target_mask`` everything is 0 and invalid."""
        th, tw = target.height, target.width
        if target_mask is not None and target_mask.shape != (th, tw):
            raise ValueError(f"target_mask must be {th}x{tw}, got {target_mask.shape}")
        t0 = time.perf_counter()
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
        k = np.clip(np.ceil(scale - FOOTPRINT_EPS), 1, MAX_FOOTPRINT).astype(np.intp)
        x0 = np.floor(col - 0.5 * k + 0.5).astype(np.intp)
        y0 = np.floor(row - 0.5 * k + 0.5).astype(np.intp)
        t1 = time.perf_counter()

        key = (cw.view(np.uint32).astype(np.uint64) << np.uint64(32)) | front.astype(np.uint64)
        zbuf = np.full(th * tw, _EMPTY, dtype=np.uint64)
        kmax = int(k.max(initial=1))
        for dy in range(kmax):
            for dx in range(kmax):
                x, y = x0 + dx, y0 + dy
                sel = (x >= 0) & (x < tw) & (y >= 0) & (y < th)
                if dx or dy:
                    sel &= k > max(dx, dy)
                np.minimum.at(zbuf, y[sel] * tw + x[sel], key[sel])
        valid = zbuf != _EMPTY
        if target_mask is not None:
            valid &= target_mask.ravel().astype(bool)
        out = np.zeros((th * tw, self.channels), dtype=np.float32)
        winners = (zbuf[valid] & np.uint64(0xFFFFFFFF)).astype(np.intp)
        out[valid] = self.colours[winners]
        out, valid = out.reshape(th, tw, -1), valid.reshape(th, tw)
        t2 = time.perf_counter()

        if fill:
            out = push_pull(out, valid.astype(np.float32))
            if target_mask is not None:
                out[~target_mask.astype(bool)] = 0.0
        t3 = time.perf_counter()
        return out, valid, {"project": (t1 - t0) * 1e3, "splat": (t2 - t1) * 1e3, "fill": (t3 - t2) * 1e3}


def pixel_warp(image: np.ndarray, depth: np.ndarray, source: Camera, target: Camera, target_mask: np.ndarray | None = None, fill: bool = True) -> tuple[np.ndarray, np.ndarray, Timings]:
    """Unproject and warp in one call (see :class:`PixelWarp`); timings include ``unproject``."""
    pw = PixelWarp(image, depth, source)
    out, valid, timings = pw.warp(target, target_mask, fill)
    return out, valid, {"unproject": pw.bind_ms} | timings
