"""Narrow-band signed distance volumes, meshed with marching cubes into watertight meshes.

A `Volume` is a regular voxel grid over a padded box. Fields on it hold signed distances (negative
inside) that are only accurate within `band` of a surface: far away they stay near +band. Each
primitive is evaluated only in its own bounding box grown by the band, which keeps hundreds of tube
segments cheap. Because the padding keeps every surface off the grid boundary, marching cubes always
closes the surface.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np
from skimage.measure import marching_cubes

from gicore.mesh import Mesh

Coords = tuple[np.ndarray, np.ndarray, np.ndarray]


def smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum: a union that fillets the crease with a blend of width ~k."""
    if k <= 0:
        return np.minimum(a, b)
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * (k / 4)


def smooth_max(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth maximum, used to carve (intersect with a complement) with a soft edge."""
    return -smooth_min(-a, -b, k)


def rotation(axis: str, angle: float) -> np.ndarray:
    """3x3 rotation by `angle` radians about the world axis 'x', 'y' or 'z' (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


class Volume:
    """A padded voxel grid covering the box [lo, hi] with cubic voxels of edge `voxel`."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, voxel: float, band: float) -> None:
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        self.voxel = float(voxel)
        self.band = float(max(band, 3 * voxel))
        pad = 2 * self.voxel  # surfaces never touch the boundary, so marching cubes closes them
        self.origin = lo - pad
        shape = np.ceil((hi - lo + 2 * pad) / self.voxel).astype(int) + 1
        self.shape = tuple(int(n) for n in shape)
        self.axes = [(self.origin[k] + self.voxel * np.arange(n)).astype(np.float32) for k, n in enumerate(self.shape)]

    def empty(self) -> np.ndarray:
        """A field with nothing in it (everything outside)."""
        return np.full(self.shape, self.band, dtype=np.float32)

    def _window(self, lo: np.ndarray, hi: np.ndarray) -> tuple[tuple[slice, ...], Coords] | None:
        """Slices and broadcastable coordinates of the voxels in [lo, hi] grown by the band."""
        first = np.floor((np.asarray(lo) - self.band - self.origin) / self.voxel).astype(int)
        last = np.ceil((np.asarray(hi) + self.band - self.origin) / self.voxel).astype(int) + 1
        first = np.clip(first, 0, self.shape)
        last = np.clip(last, 0, self.shape)
        if np.any(last <= first):
            return None
        slices = tuple(slice(int(a), int(b)) for a, b in zip(first, last, strict=True))
        x = self.axes[0][slices[0]][:, None, None]
        y = self.axes[1][slices[1]][None, :, None]
        z = self.axes[2][slices[2]][None, None, :]
        return slices, (x, y, z)

    def _apply(
        self,
        field: np.ndarray,
        lo: np.ndarray,
        hi: np.ndarray,
        distance: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
        k: float,
        carve: bool,
    ) -> None:
        window = self._window(lo, hi)
        if window is None:
            return
        slices, (x, y, z) = window
        d = distance(x, y, z)
        if carve:
            field[slices] = smooth_max(field[slices], -d, k)
        else:
            field[slices] = smooth_min(field[slices], d, k)

    def ellipsoid(
        self,
        field: np.ndarray,
        centre: np.ndarray,
        radii: np.ndarray,
        orientation: np.ndarray | None = None,
        k: float = 0.0,
        carve: bool = False,
        taper: float = 0.0,
    ) -> None:
        """Union (or with carve=True, subtract) an ellipsoid, blending over width k.

        orientation: 3x3 matrix whose columns are the ellipsoid's axes in world space.
        taper: the cross-section (first and third axes) scales by 1 + taper * y / r_y along the
            second axis, so a negative taper makes an egg that is broad below and narrow above.
        """
        c = np.asarray(centre, dtype=np.float32)
        r = np.asarray(radii, dtype=np.float32)
        rot = np.asarray(np.eye(3) if orientation is None else orientation, dtype=np.float32)
        # Half extent of the rotated (and possibly tapered) ellipsoid's bounding box.
        reach = np.abs(rot) @ (r * np.float32([1 + abs(taper), 1, 1 + abs(taper)]))

        def distance(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
            dx, dy, dz = x - c[0], y - c[1], z - c[2]
            q = [dx * rot[0, axis] + dy * rot[1, axis] + dz * rot[2, axis] for axis in range(3)]
            if taper:
                # Clipped so the warp never folds over; its sign stays exact, distance approximate.
                scale = np.clip(1 + taper * q[1] / r[1], 0.2, 1 + abs(taper))
                q[0], q[2] = q[0] / scale, q[2] / scale
            # Inigo Quilez's bound: exact sign, close to the true distance near the surface.
            k0 = np.sqrt(sum((q[axis] / r[axis]) ** 2 for axis in range(3)))
            k1 = np.sqrt(sum((q[axis] / r[axis] ** 2) ** 2 for axis in range(3)))
            return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)

        self._apply(field, c - reach, c + reach, distance, k, carve)

    def tube(
        self,
        field: np.ndarray,
        points: np.ndarray,
        radii: np.ndarray | float,
        k: float = 0.0,
    ) -> None:
        """Union a tube swept along a polyline, radius linearly interpolated between its points.

        Segments join with a hard union (their round ends match); k blends the tube into the field.
        """
        p = np.asarray(points, dtype=np.float32)
        r = np.broadcast_to(np.asarray(radii, dtype=np.float32), (len(p),))
        own = self.empty() if k > 0 else field
        for a, b, ra, rb in zip(p[:-1], p[1:], r[:-1], r[1:], strict=True):
            reach = max(ra, rb)
            self._apply(
                own,
                np.minimum(a, b) - reach,
                np.maximum(a, b) + reach,
                partial(_segment_distance, a=a, b=b, ra=ra, rb=rb),
                k=0.0,
                carve=False,
            )
        if k > 0:
            field[...] = smooth_min(field, own, k)

    def to_mesh(self, field: np.ndarray) -> Mesh:
        """Mesh the zero level set; faces wound so normals point out of the negative region."""
        f = np.asarray(field, dtype=np.float32)
        if f.min() >= 0:
            raise ValueError("the field encloses no volume")
        # A corner exactly on the level would create coincident vertices; nudge it off the surface.
        f = np.where(np.abs(f) < 1e-7, np.float32(1e-7), f)
        # An outside boundary layer closes any surface that strays beyond the padded box.
        f[[0, -1], :, :] = self.band
        f[:, [0, -1], :] = self.band
        f[:, :, [0, -1]] = self.band
        verts, faces, _, _ = marching_cubes(f, 0.0, spacing=(self.voxel,) * 3)
        verts = verts + self.origin
        tri = verts[faces]
        signed_volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()
        if signed_volume < 0:
            faces = faces[:, ::-1]
        return Mesh(verts, faces)


def _segment_distance(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, a: np.ndarray, b: np.ndarray, ra: float, rb: float
) -> np.ndarray:
    """Distance to a capsule from a to b whose radius goes linearly from ra to rb."""
    ba = b - a
    px, py, pz = x - a[0], y - a[1], z - a[2]
    t = (px * ba[0] + py * ba[1] + pz * ba[2]) / max(float(ba @ ba), 1e-12)
    t = np.clip(t, 0.0, 1.0)
    dx, dy, dz = px - ba[0] * t, py - ba[1] * t, pz - ba[2] * t
    return np.sqrt(dx * dx + dy * dy + dz * dz) - (ra + (rb - ra) * t)
