"""Where two renders of G-buffers may be compared pixel by pixel: away from silhouettes.

At a silhouette a pixel centre and a point elsewhere in the pixel (another renderer's sample, or the same
renderer on other triangles) can hit different surfaces; :func:`silhouettes` marks those pixels, so that
``gicore.gl.fidelity`` (GL against Mitsuba) and ``gicore.gl.lod`` (a level of detail against full detail)
compare the interiors only and count the rest apart.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: A depth step between neighbours larger than this fraction of the depth is a discontinuity, beyond what
#: any surface's slope gives between pixel centres (a grazing plane at the scenes' cameras: < 2 %).
DEPTH_JUMP = 0.05


def _dilate(edge: np.ndarray) -> np.ndarray:
    """Pixels with an ``edge`` pixel in their 3x3 neighbourhood."""
    padded = np.pad(edge, 1)
    h, w = edge.shape
    return np.any([padded[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)


def _changes(x: np.ndarray, differ: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """HxW: where ``x`` (HxW...) differs from its right or lower neighbour (both pixels marked)."""
    edge = np.zeros(x.shape[:2], dtype=bool)
    dx, dy = differ(x[:, 1:], x[:, :-1]), differ(x[1:], x[:-1])
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:] |= dy
    edge[:-1] |= dy
    return edge


def silhouettes(*gbuffers: dict[str, np.ndarray], depth_jump: float = DEPTH_JUMP) -> np.ndarray:
    """HxW bool: pixels near a change of surface (mask), object (albedo) or a depth discontinuity in any of
    the given G-buffer sets, or whose masks disagree between them."""
    edge = np.zeros(gbuffers[0]["mask"].shape[:2], dtype=bool)
    for gb in gbuffers:
        edge |= _changes(gb["mask"][..., 0] > 0.5, np.not_equal)
        edge |= _changes(gb["albedo"], lambda a, b: np.any(np.abs(a - b) > 1e-6, axis=-1))
        d = gb["depth"][..., 0]
        edge |= _changes(d, lambda a, b: np.abs(a - b) > depth_jump * np.maximum(np.minimum(a, b), 1e-9))
    masks = [gb["mask"][..., 0] > 0.5 for gb in gbuffers]
    for m in masks[1:]:
        edge |= m != masks[0]
    return _dilate(edge)
