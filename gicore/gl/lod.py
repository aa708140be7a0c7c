"""Levels of detail of a scene's meshes for :class:`gicore.gl.renderer.GLRenderer` (what a Web3D client does).

A CPU rasteriser is vertex-bound, so real-time clients draw each view at a level of detail chosen by the error
it costs; so does the GL renderer. Level ``k`` keeps :data:`LOD_RATIOS` ``[k]`` of each large mesh's triangles
(quadric edge-collapse decimation, ``fast_simplification``; meshes below :data:`MIN_TRIANGLES` stay whole), with
the full mesh's smooth normals carried over (:func:`transfer_normals`). :func:`lod_errors` measures a level's
G-buffer error against full detail at a view (``normal``, ``depth``, ``mask``, away from silhouettes);
:data:`LOD_BOUND`, the default bound of ``lod="auto"``, is about one sub-pixel shift of the samples.
docs/architecture.md, Level of detail.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gicore.camera import Camera
from gicore.gl.edges import silhouettes
from gicore.mesh import Mesh
from gicore.scene import SceneSpec

#: Fraction of a large mesh's triangles each level keeps (level 0: all of them).
LOD_RATIOS = (1.0, 1 / 2, 1 / 4, 1 / 8, 1 / 16, 1 / 32)
#: ``lod`` as a command-line option gives it (:func:`lod_value`): "auto", "full" or a level's index.
LOD_CHOICES = ("auto", "full", *(str(k) for k in range(len(LOD_RATIOS))))
#: Meshes with fewer triangles are not decimated (the environment's quads, small user meshes).
MIN_TRIANGLES = 2048
#: ``fast_simplification``'s aggressiveness (0 to 10, default 7): 4 lowers the normal error of a level by 10 to
#: 15 % at the same triangle count (lung_plane, levels 2-4, measured) and still reaches the target counts; 2
#: stops short of them.
AGGRESSIVENESS = 4.0
#: Nearest full-mesh vertices whose normals a decimated vertex's normal is blended from.
NORMAL_NEIGHBOURS = 4


@dataclass(frozen=True)
class LevelMesh:
    """One level of one object's mesh: the triangles and their smooth shading normals (per vertex)."""

    mesh: Mesh
    normals: np.ndarray

    @property
    def n_triangles(self) -> int:
        return self.mesh.n_triangles


def decimate(mesh: Mesh, ratio: float) -> Mesh:
    """``mesh`` decimated to about ``ratio`` of its triangles (quadric edge collapse); unused vertices dropped."""
    if not 0.0 < ratio <= 1.0:
        raise ValueError(f"ratio must lie in (0, 1], got {ratio}")
    if ratio == 1.0:
        return mesh
    import fast_simplification

    target = max(4, round(mesh.n_triangles * ratio))
    v, f = fast_simplification.simplify(mesh.vertices, mesh.faces, target_count=target, agg=AGGRESSIVENESS)
    used = np.unique(f)
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return Mesh(v[used], remap[f])


def transfer_normals(full: Mesh, full_normals: np.ndarray, coarse: Mesh) -> np.ndarray:
    """Unit normals at ``coarse``'s vertices: the inverse-distance blend of the normals of the
    :data:`NORMAL_NEIGHBOURS` nearest vertices of ``full`` (a smooth field sampled where the coarse mesh
    has its vertices); falls back to ``coarse``'s own normal where the blend cancels."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(full.vertices).query(coarse.vertices, k=NORMAL_NEIGHBOURS)
    w = 1.0 / np.maximum(dist, 1e-9)
    n = np.einsum("ik,ikj->ij", w, full_normals[idx].astype(np.float64))
    length = np.linalg.norm(n, axis=1, keepdims=True)
    own = coarse.vertex_normals().astype(np.float64)
    return np.where(length > 1e-6, n / np.maximum(length, 1e-12), own).astype(np.float32)


def mesh_levels(mesh: Mesh, ratios=LOD_RATIOS, min_triangles: int = MIN_TRIANGLES) -> list[LevelMesh]:
    """One :class:`LevelMesh` per ratio: decimated (with transferred normals) when ``mesh`` has at least
    ``min_triangles`` triangles, else the mesh itself at every level."""
    normals = mesh.vertex_normals()
    full = LevelMesh(mesh, normals)
    if mesh.n_triangles < min_triangles:
        return [full] * len(ratios)
    out = []
    for ratio in ratios:
        if ratio >= 1.0:
            out.append(full)
            continue
        coarse = decimate(mesh, ratio)
        out.append(LevelMesh(coarse, transfer_normals(mesh, normals, coarse)))
    return out


def lod_value(choice: str) -> str | int:
    """``GLRenderer``'s ``lod`` from an option's text (one of :data:`LOD_CHOICES`): a level's index as an int."""
    if choice not in LOD_CHOICES:
        raise ValueError(f"lod must be one of {LOD_CHOICES}, got {choice!r}")
    return int(choice) if choice.isdigit() else choice


#: G-buffer error channels of a level against full detail (see the module docstring).
LOD_CHANNELS = ("normal", "depth", "coverage")
#: Default bound of ``lod="auto"`` per channel, about one sub-pixel jitter of the samples: Mitsuba's jittered
#: G-buffers (the shipped model's training data) against its centre-sampled ones, by :func:`lod_errors` on 4
#: GI-camera views each of the plane scenes at 256², differ by normal 1.0e-3 to 3.3e-3 (vessels < 2.1e-4: their
#: interior is mostly the plane), depth 2.4e-3 to 3.0e-3, coverage 2.0e-3 to 5.6e-3. The model does not see
#: that difference: its SSIM against path-traced GT (``bench quality --renderers``;
#: 8 held-out GI views per scene, 256 spp + OIDN) moves by 0.0001 to
#: 0.0008 between the two; and on GL inputs levels 1-4 stay within 0.0003 of full detail (lung_plane,
#: digestive_plane, vessels_plane, lung_cornell), where level 4 has normal error up to 2.8e-3 on lung_plane's
#: path; level 5 (normal 3.0e-3 and more) loses up to 0.0013.
LOD_BOUND = {"normal": 3e-3, "depth": 1e-3, "coverage": 1e-3}
#: Bound of ``lod="auto"`` for the passes that are only shown (a client frame's DI with its warp's pass,
#: ``GLRenderer.render_di_raster``), on the same error model: looser, since no network reads them. A shown
#: GIGAN frame (the shipped model's map, structure-aware warp, eq. 1 at tau 0) at the level this bound picks
#: scores SSIM 0.9979-0.9990 (min) and 0.9989-0.9995 (mean) against the same frame at full detail, on 30 local
#: views each of the five built-in scenes at 256², where the model-input bound keeps level 0-2 (the frames' DI
#: alone: 0.986-0.995); the pass then costs 8.8-11.5 ms instead of 11.4-14.1 at full detail (one core,
#: llvmpipe; levels 1.6-3.6 on average).
SHOWN_LOD_BOUND = {"normal": 1e-2, "depth": 1e-3, "coverage": 1e-3}
#: Calibration of ``lod="auto"``: views of the scene's GI-camera path (a seed of their own), each also moved
#: towards and away from its target by these factors, so that the fit sees close-ups and distant views.
CALIBRATION_VIEWS = 4
CALIBRATION_DISTANCES = (0.7, 1.0, 1.4)
CALIBRATION_SEED = 7
#: Slopes of the fitted power laws are clamped to this range (log-log; measured 2 to 4).
SLOPE_RANGE = (0.0, 8.0)


def lod_errors(level: dict[str, np.ndarray], full: dict[str, np.ndarray]) -> dict[str, float]:
    """{normal, depth, coverage} error of G-buffers ``level`` against ``full`` at the same camera (see the
    module docstring)."""
    m_level, m_full = level["mask"][..., 0] > 0.5, full["mask"][..., 0] > 0.5
    moved = (m_level != m_full) | np.any(np.abs(level["albedo"] - full["albedo"]) > 1e-6, axis=-1)
    coverage = float(moved.mean())
    interior = ~silhouettes(level, full) & m_full & m_level
    if not interior.any():
        return {"normal": 0.0, "depth": 0.0, "coverage": coverage}
    dn = np.abs(level["normal"].astype(np.float64) - full["normal"]).max(axis=-1)[interior]
    d_full = full["depth"][..., 0].astype(np.float64)[interior]
    dd = np.abs(level["depth"][..., 0].astype(np.float64)[interior] - d_full) / d_full
    return {"normal": float(dn.mean()), "depth": float(dd.mean()), "coverage": coverage}


def within(errors: dict[str, float], bound: dict[str, float]) -> bool:
    """Every channel of ``bound`` within it in ``errors``."""
    return all(errors[c] <= bound[c] for c in bound)


def pixel_scale(camera: Camera, centre: np.ndarray) -> float:
    """Pixels per scene unit at ``centre`` seen from ``camera`` (focal length in pixels over distance)."""
    focal = 0.5 * camera.width / math.tan(math.radians(camera.fov) / 2.0)
    return focal / max(float(np.linalg.norm(np.subtract(camera.origin, centre))), camera.near)


def calibration_views(spec: SceneSpec, resolution: int) -> list[Camera]:
    """The calibration views of ``lod="auto"``: :data:`CALIBRATION_VIEWS` GI cameras of the scene's path,
    each at :data:`CALIBRATION_DISTANCES` times its distance to its target."""
    from gicore.paths import camera_path

    views = []
    for cam in camera_path(spec, CALIBRATION_VIEWS, seed=CALIBRATION_SEED, resolution=resolution):
        o, t = np.asarray(cam.origin, dtype=np.float64), np.asarray(cam.target, dtype=np.float64)
        views += [replace(cam, origin=tuple(float(x) for x in t + f * (o - t))) for f in CALIBRATION_DISTANCES]
    return views


def fit_envelope(scales: np.ndarray, errors: np.ndarray) -> tuple[float, float]:
    """(log a, p) of the power law a * scale**p fitted to the positive errors (least squares in log-log, the
    slope clamped to :data:`SLOPE_RANGE`) and raised until no sample lies above it; (-inf, 0) when no
    error is positive."""
    pos = errors > 0
    if not pos.any():
        return -math.inf, 0.0
    x, y = np.log(scales[pos]), np.log(errors[pos])
    p = float(np.polyfit(x, y, 1)[0]) if pos.sum() > 1 and np.ptp(x) > 1e-9 else 0.0
    p = min(max(p, SLOPE_RANGE[0]), SLOPE_RANGE[1])
    return float(np.max(y - p * x)), p


@dataclass
class ErrorModel:
    """Predicted G-buffer error of each level at a pixel scale (:func:`pixel_scale`): per level and channel
    an upper envelope ``exp(log_a) * scale**p`` of the errors measured on the calibration views.

    ``samples``: the calibration, one row per (view, level): ``view``, ``scale``, ``level``, and the
    measured error per channel."""

    coefficients: list[dict[str, tuple[float, float]]]
    samples: list[dict[str, Any]]
    centre: np.ndarray

    def predict(self, level: int, scale: float) -> dict[str, float]:
        if level == 0:
            return dict.fromkeys(LOD_CHANNELS, 0.0)
        return {c: math.exp(a + p * math.log(scale)) for c, (a, p) in self.coefficients[level].items()}

    def level(self, camera: Camera, bound: dict[str, float]) -> int:
        """The coarsest level whose predicted error at ``camera`` is within ``bound`` (0 if none is)."""
        scale = pixel_scale(camera, self.centre)
        for level in range(len(self.coefficients) - 1, 0, -1):
            if within(self.predict(level, scale), bound):
                return level
        return 0


def calibrate(
    render_level: Callable[[Camera, int], dict[str, np.ndarray]],
    n_levels: int,
    views: list[Camera],
    centre: np.ndarray,
) -> ErrorModel:
    """Measure every level's :func:`lod_errors` on ``views`` (``render_level(camera, level)`` gives G-buffers)
    and fit its :class:`ErrorModel`; ``centre``: where the pixel scale is taken (the decimated objects)."""
    samples = []
    for i, cam in enumerate(views):
        full = render_level(cam, 0)
        scale = pixel_scale(cam, centre)
        for level in range(1, n_levels):
            samples.append({"view": i, "scale": scale, "level": level} | lod_errors(render_level(cam, level), full))
    coefficients: list[dict[str, tuple[float, float]]] = [{}]
    for level in range(1, n_levels):
        rows = [r for r in samples if r["level"] == level]
        scales = np.array([r["scale"] for r in rows])
        coefficients.append({c: fit_envelope(scales, np.array([r[c] for r in rows])) for c in LOD_CHANNELS})
    return ErrorModel(coefficients, samples, np.asarray(centre, dtype=np.float64))
