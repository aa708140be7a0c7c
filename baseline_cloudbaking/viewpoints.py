"""What selects a stored GI map: its key (the tree path of scene and light cell, and the map format) and a
viewpoint within a :class:`Tolerance` of the request's, the nearest one winning (docs/architecture.md, GI tree).

The rule is pure: the GI tree (:mod:`baseline_cloudbaking.store`) applies it to the viewpoints of its index,
the clients to the maps they hold, and the benches and the prebaker to plan fills without a store
(:class:`ViewSet`, :class:`CellViews`, :func:`simulate_fill`, :func:`fewest_maps`).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Tolerance:
    """How far a stored viewpoint may be from a requested one and still serve it."""

    #: Largest eye distance, scene units.
    position: float = 0.05
    #: Largest angle between the view directions, degrees.
    angle_deg: float = 2.0

    def __post_init__(self) -> None:
        for name in ("position", "angle_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"tolerance {name} must be finite and >= 0, got {v}")

    @classmethod
    def parse(cls, text: str) -> Tolerance:
        """The tolerance written ``DP:DTHETA`` (scene units : degrees), e.g. ``0.05:2``; ValueError otherwise."""
        try:
            dp, angle = (float(v) for v in text.split(":"))
            return cls(dp, angle)
        except ValueError:
            raise ValueError(f"{text!r} is not DP:DTHETA, two finite numbers >= 0") from None


@dataclass(frozen=True)
class Viewpoint:
    """Eye position and unit view direction of a GI camera."""

    eye: Vec3
    direction: Vec3

    @classmethod
    def look_at(cls, eye: Vec3, target: Vec3) -> Viewpoint:
        """Plain floats (a server makes one per request; numpy's per-call cost was most of it)."""
        e = tuple(map(float, eye))
        d = [float(t) - c for t, c in zip(target, e, strict=True)]
        n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if not (math.isfinite(n) and n > 0.0):
            raise ValueError(f"eye {eye} and target {target} must be distinct finite points")
        return cls(e, (d[0] / n, d[1] / n, d[2] / n))  # type: ignore[arg-type]


@dataclass(frozen=True)
class MapKey:
    """Everything but the viewpoint that selects maps: the tree path (scene, light cell) and the map
    format (resolution, GI-camera FOV, codec, spp, whether the GI view's DI is included)."""

    scene: str
    light_cell: tuple[int, int, int] | None
    resolution: int
    fov: float
    codec: str
    spp: int
    di: bool

    @property
    def cell_text(self) -> str | None:
        return None if self.light_cell is None else ",".join(map(str, self.light_cell))


def light_cell(light: Vec3, cell_size: float | None) -> tuple[int, int, int] | None:
    """The light level of a key: the grid cell of side ``cell_size`` holding ``light``; ``None`` (no
    light level) when ``cell_size`` is None, i.e. the scene's light does not move."""
    if cell_size is None:
        return None
    if not (math.isfinite(cell_size) and cell_size > 0.0):
        raise ValueError(f"light cell size must be finite and > 0, got {cell_size}")
    return tuple(math.floor(c / cell_size) for c in light)  # type: ignore[return-value]


def nearest(eyes: np.ndarray, dirs: np.ndarray, view: Viewpoint, tol: Tolerance) -> tuple[int, float, float] | None:
    """Index, eye distance and angle (degrees) of the stored viewpoint (rows of ``eyes``/``dirs``) that
    best matches ``view`` within ``tol``, or None. Best = smallest sum of squared tolerance-relative
    distance and angle. Angles use atan2(|a x b|, a.b), exact for tiny angles."""
    if len(eyes) == 0:
        return None
    dp = np.linalg.norm(eyes - np.asarray(view.eye), axis=1)
    d = np.asarray(view.direction)
    angle = np.degrees(np.arctan2(np.linalg.norm(np.cross(dirs, d), axis=1), dirs @ d))
    ok = (dp <= tol.position) & (angle <= tol.angle_deg)
    if not ok.any():
        return None
    score = (dp / max(tol.position, 1e-12)) ** 2 + (angle / max(tol.angle_deg, 1e-12)) ** 2
    i = int(np.argmin(np.where(ok, score, np.inf)))
    return i, float(dp[i]), float(angle[i])


#: Up to this many candidates, :func:`_nearest_few` (plain floats) is cheaper than numpy's per-call cost.
_FEW = 16


def _nearest_few(rows: list[tuple[float, ...]], view: Viewpoint, tol: Tolerance) -> tuple[int, float, float] | None:
    """:func:`nearest` for a few (ex, ey, ez, dx, dy, dz) rows, in plain floats: the same rule and formulas."""
    (x, y, z), (a, b, c) = view.eye, view.direction
    best, best_score = None, math.inf
    for i, (ex, ey, ez, dx, dy, dz) in enumerate(rows):
        dp = math.sqrt((ex - x) ** 2 + (ey - y) ** 2 + (ez - z) ** 2)
        cross = math.sqrt((dy * c - dz * b) ** 2 + (dz * a - dx * c) ** 2 + (dx * b - dy * a) ** 2)
        angle = math.degrees(math.atan2(cross, dx * a + dy * b + dz * c))
        if dp <= tol.position and angle <= tol.angle_deg:
            score = (dp / max(tol.position, 1e-12)) ** 2 + (angle / max(tol.angle_deg, 1e-12)) ** 2
            if score < best_score:
                best, best_score = (i, dp, angle), score
    return best


class ViewSet:
    """Viewpoints in memory (one light cell, one format), for planning a fill without a store."""

    def __init__(self) -> None:
        self._eyes = np.empty((16, 3))
        self._dirs = np.empty((16, 3))
        self.n = 0

    def add(self, view: Viewpoint) -> None:
        if self.n == len(self._eyes):
            self._eyes = np.concatenate([self._eyes, np.empty_like(self._eyes)])
            self._dirs = np.concatenate([self._dirs, np.empty_like(self._dirs)])
        self._eyes[self.n], self._dirs[self.n] = view.eye, view.direction
        self.n += 1

    def nearest(self, view: Viewpoint, tol: Tolerance) -> tuple[int, float, float] | None:
        return nearest(self._eyes[: self.n], self._dirs[: self.n], view, tol)


class CellViews:
    """Viewpoints in memory by light cell, each with an id: the GI tree's lookup over maps held without a store."""

    def __init__(self) -> None:
        self._cells: dict[Any, tuple[ViewSet, list[int]]] = {}

    def add(self, view: Viewpoint, cell: Any, entry: int) -> None:
        if cell not in self._cells:
            self._cells[cell] = (ViewSet(), [])
        views, ids = self._cells[cell]
        views.add(view)
        ids.append(entry)

    def find(self, view: Viewpoint, cell: Any, tol: Tolerance) -> int | None:
        """The id of the viewpoint in ``cell`` that serves ``view`` within ``tol`` (the nearest), or None."""
        held = self._cells.get(cell)
        found = None if held is None else held[0].nearest(view, tol)
        return None if found is None else held[1][found[0]]


def simulate_fill(views: list[Viewpoint], cells: list[Any], tol: Tolerance) -> list[int]:
    """Walk a path through an empty tree, inserting on every miss: returns, per frame, the index of
    the entry that serves it (entries are numbered in insertion order; a new index marks a miss)."""
    stored = CellViews()
    served: list[int] = []
    n_entries = 0
    for view, cell in zip(views, cells, strict=True):
        entry = stored.find(view, cell, tol)
        if entry is None:
            entry, n_entries = n_entries, n_entries + 1
            stored.add(view, cell, entry)
        served.append(entry)
    return served


def fewest_maps(views: list[Viewpoint], cells: list[Any], maps: list[tuple[Viewpoint, Any]], tol: Tolerance) -> int:
    """The fewest of ``maps`` (viewpoint, light cell) that serve every view of a path (``views`` with their
    ``cells``, in order) by the GI tree's rule, each view by a map within ``tol`` in its cell: a floor for any
    request policy of a client that must show each view a map within tolerance. Each map serves runs of
    consecutive views; covering the path by such runs, always taking the run reaching farthest from the first
    view not yet served, is optimal for runs. ValueError when some view no map serves."""
    runs: list[tuple[int, int]] = []
    for eye, direction, cell in ((m.eye, m.direction, c) for m, c in maps):
        start = None
        for i, (view, view_cell) in enumerate(zip(views, cells, strict=True)):
            served = view_cell == cell and nearest(np.array([eye]), np.array([direction]), view, tol) is not None
            if served and start is None:
                start = i
            elif not served and start is not None:
                runs.append((start, i - 1))
                start = None
        if start is not None:
            runs.append((start, len(views) - 1))
    count, first = 0, 0
    while first < len(views):
        reach = max((end for start, end in runs if start <= first <= end), default=None)
        if reach is None:
            raise ValueError(f"no map serves view {first} of the path")
        count, first = count + 1, reach + 1
    return count


@dataclass(frozen=True)
class GroupViews:
    """The viewpoints of one key group (scene, light cell, resolution, codec, spp) in memory, sorted by the
    eye's x (as the index's ``entries_key``) so that a lookup reads only the slab of x within the tolerance;
    FOV and DI are filtered per lookup, as the index's query does."""

    xs: list[float]  # eye x, ascending
    rows: list[tuple]  # (ex, ey, ez, dx, dy, dz, fov, di, id, sha), in the order of xs
    max_id: int  # the largest entry id read (0: none)

    @classmethod
    def from_rows(cls, rows: list[tuple], base: GroupViews | None = None) -> GroupViews:
        """From index rows (id, sha, fov, di, ex, ey, ez, dx, dy, dz), added to ``base``'s when given: rows
        newer than all of ``base``'s (their ids are larger) go after its equal x, as the index orders them."""
        new = sorted((r[4:10] + (r[2], r[3], r[0], r[1]) for r in rows), key=lambda r: (r[0], r[8]))
        max_id = max([base.max_id if base else 0, *(r[0] for r in rows)])
        if base is None:
            return cls([r[0] for r in new], new, max_id)
        xs, ordered = base.xs.copy(), base.rows.copy()  # copies: lookups on other threads read the old lists
        for row in new:
            i = bisect.bisect_right(xs, row[0])
            xs.insert(i, row[0])
            ordered.insert(i, row)
        return cls(xs, ordered, max_id)

    def find(self, key: MapKey, view: Viewpoint, tol: Tolerance) -> tuple[int, str, float, float] | None:
        """The best of the group's maps in ``key``'s FOV and DI for ``view``, as an index query would find it:
        the box of side 2 x ``tol.position`` around the eye (inclusive, as SQL's BETWEEN), then the nearest
        within tolerance."""
        (x, y, z), r = view.eye, tol.position
        lo, hi = bisect.bisect_left(self.xs, x - r), bisect.bisect_right(self.xs, x + r)
        candidates = [
            row
            for row in self.rows[lo:hi]
            if y - r <= row[1] <= y + r
            and z - r <= row[2] <= z + r
            and row[7] >= key.di
            and abs(row[6] - key.fov) < 1e-6
        ]
        if not candidates:
            return None
        if len(candidates) <= _FEW:
            found = _nearest_few([row[:6] for row in candidates], view, tol)
        else:
            arr = np.array([row[:6] for row in candidates], dtype=np.float64)
            found = nearest(arr[:, :3], arr[:, 3:], view, tol)
        if found is None:
            return None
        i, dist, angle = found
        return candidates[i][8], candidates[i][9], dist, angle
