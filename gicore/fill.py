"""Hole filling shared by both warps: a push-pull pyramid (Gortler et al. 1996, "The Lumigraph")."""

from __future__ import annotations

import numpy as np


def push_pull(image: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Fill pixels of zero ``weight`` (HxW, in [0, 1]) from weighted neighbours by a push-pull pyramid.

    Pull: halve the resolution with weight-normalised 2x2 averages until one pixel is left. Push: from
    coarse to fine, each pixel keeps ``weight * own + (1 - weight) * coarser``. Pixels of weight 1 are
    unchanged; holes get smooth values from the nearest valid pixels at every scale. All-zero weight
    gives zeros. NaN or Inf in either input is refused (ValueError): even at zero weight it would spread
    through the pyramid into every hole.
    """
    img = np.asarray(image, dtype=np.float32)
    wgt = np.asarray(weight, dtype=np.float32)
    for name, arr in (("image", img), ("weight", wgt)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"push_pull {name} contains NaN or Inf")
    if img.ndim != 3 or wgt.shape != img.shape[:2]:
        raise ValueError(f"push_pull needs an HxWxC image and an HxW weight, got {img.shape} and {wgt.shape}")
    wgt = np.clip(wgt, 0.0, 1.0)
    levels: list[tuple[np.ndarray, np.ndarray]] = []
    col, w = img * wgt[..., None], wgt
    while max(col.shape[:2]) > 1:
        levels.append((col, w))
        h, wd = col.shape[:2]
        if h % 2 or wd % 2:  # odd sizes: zero-weight padding so 2x2 blocks tile the level
            col = np.pad(col, ((0, h % 2), (0, wd % 2), (0, 0)))
            w = np.pad(w, ((0, h % 2), (0, wd % 2)))
        csum = col[0::2, 0::2] + col[1::2, 0::2] + col[0::2, 1::2] + col[1::2, 1::2]
        wsum = w[0::2, 0::2] + w[1::2, 0::2] + w[0::2, 1::2] + w[1::2, 1::2]
        # store colour premultiplied by the (clipped) weight: a texel with any support counts fully
        w = np.minimum(wsum, 1.0)
        col = csum * (w / np.maximum(wsum, 1e-12))[..., None]
    coarse = col / np.maximum(w, 1e-12)[..., None]
    for col, w in reversed(levels):
        h, wd = col.shape[:2]
        up = np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)[:h, :wd]
        coarse = col + (1.0 - w)[..., None] * up  # col is premultiplied by w
    return coarse
