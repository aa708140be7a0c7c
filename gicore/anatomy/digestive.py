"""Procedural digestive tract: esophagus, stomach, duodenum, small intestine and colon.

Modelled parts (patient's left on +x, anterior +z, y up, about one unit tall), each a tube swept
along a Catmull-Rom spline with a radius that varies along its length:
- the esophagus, descending to the cardia;
- a J-shaped stomach: a wide fundus and body on the patient's left narrowing through the antrum to
  the pylorus;
- the C-shaped duodenum ending at the duodenojejunal flexure;
- the small intestine (jejunum and ileum): a thin tube coiled through the central abdomen along a
  seeded random Hamiltonian path on a 3D lattice (backbite moves), so its loops pack densely without
  crossing, from the flexure (upper left) to the ileocecal junction (lower right);
- the colon framing it: cecum with appendix, ascending colon, hepatic flexure, a sagging transverse
  colon in front, the higher splenic flexure, descending colon, sigmoid loop and rectum, its wall
  ringed by haustra (periodic constrictions).

Parameters: `seed` drives the small-intestine coil, the jitter of every spline control point and
the haustra spacing; `detail` scales the grid resolution (voxel = 0.0085 / detail units). Tube radii
are floored at one voxel so thin parts (the appendix) stay in one piece at low detail.
"""

from __future__ import annotations

import numpy as np

from gicore.anatomy.curves import catmull_rom, resample
from gicore.anatomy.sdf import Volume
from gicore.mesh import Mesh

BASE_VOXEL = 0.0085

ESOPHAGUS = ((0.0, 1.10, -0.05), (0.02, 0.94, -0.04), (0.07, 0.84, -0.02), (0.115, 0.79, 0.0))
# Stomach centre line from the top of the fundus round the greater curvature to the pylorus,
# with the tube radius at each control point.
STOMACH = (
    ((0.17, 0.85, -0.01), 0.075),
    ((0.205, 0.76, 0.01), 0.095),
    ((0.195, 0.65, 0.03), 0.09),
    ((0.12, 0.575, 0.05), 0.07),
    ((0.03, 0.57, 0.05), 0.05),
    ((-0.04, 0.61, 0.04), 0.032),
    ((-0.07, 0.63, 0.03), 0.024),
)
DUODENUM = (
    (-0.07, 0.63, 0.03),
    (-0.125, 0.59, 0.0),
    (-0.13, 0.52, -0.03),
    (-0.08, 0.47, -0.05),
    (0.0, 0.475, -0.06),
    (0.07, 0.5, -0.07),
)
COLON = (
    (-0.21, 0.14, 0.02),  # cecum
    (-0.245, 0.25, 0.0),
    (-0.25, 0.45, -0.01),
    (-0.22, 0.57, 0.02),  # hepatic flexure
    (-0.12, 0.51, 0.10),
    (0.0, 0.48, 0.115),  # transverse colon sags in front, below the stomach
    (0.14, 0.53, 0.09),
    (0.24, 0.65, 0.0),  # splenic flexure, higher than the hepatic one
    (0.27, 0.52, -0.03),
    (0.265, 0.32, -0.03),
    (0.25, 0.16, -0.02),
    (0.20, 0.08, 0.03),  # sigmoid loop
    (0.10, 0.11, 0.06),
    (0.04, 0.07, 0.02),
    (0.0, 0.03, -0.04),  # rectum
    (0.0, -0.05, -0.05),
)
APPENDIX = ((-0.215, 0.12, 0.03), (-0.19, 0.07, 0.04), (-0.15, 0.05, 0.05))
# Lattice holding the small intestine: node counts per axis and the box they span.
COIL_NODES = (6, 5, 3)
COIL_BOX = ((-0.155, 0.14, -0.07), (0.155, 0.4, 0.09))
COIL_RADIUS = 0.023
COLON_RADIUS = 0.042
JOIN_BLEND = 0.02


def build_digestive(seed: int, detail: float) -> Mesh:
    """The digestive tract as one watertight mesh in generation units (not normalized)."""
    rng = np.random.default_rng(seed)
    voxel = BASE_VOXEL / detail
    vol = Volume((-0.32, -0.1, -0.15), (0.32, 1.14, 0.19), voxel, band=0.05)
    step = min(1.5 * voxel, 0.012)  # fine enough to resolve the haustra ripple
    field = vol.empty()

    def jittered(points: tuple, sigma: float = 0.006) -> np.ndarray:
        return np.asarray(points, dtype=np.float64) + rng.normal(0.0, sigma, (len(points), 3))

    def sweep(control: np.ndarray, radius: np.ndarray | float, k: float = JOIN_BLEND) -> None:
        path, s = resample(catmull_rom(control), step)
        if not np.isscalar(radius):  # radius given per control point: interpolate along the path
            knots = np.linspace(0.0, s[-1], len(radius))
            radius = np.interp(s, knots, radius)
        vol.tube(field, path, np.maximum(radius, voxel), k=k)  # thinner would fall apart

    sweep(jittered(ESOPHAGUS), 0.022)
    stomach = np.array([c for c, _ in STOMACH])
    sweep(jittered(stomach, 0.008), np.array([r for _, r in STOMACH]) * rng.uniform(0.92, 1.08))
    sweep(jittered(DUODENUM), 0.024)

    coil = _coil_path(rng)
    # The jejunum leaves the duodenojejunal flexure; the ileum enters the cecum medially.
    sweep(np.vstack([DUODENUM[-1], coil, (-0.2, 0.17, 0.03)]), COIL_RADIUS, k=0.01)

    colon, s = resample(catmull_rom(jittered(COLON)), step)
    period = 0.07 * rng.uniform(0.9, 1.1)
    haustra = 1.0 - 0.18 * (1.0 - np.abs(np.sin(np.pi * s / period))) ** 4
    taper = np.interp(s, [0.0, 0.3, s[-1] - 0.3, s[-1]], [1.15, 1.0, 0.85, 0.7])  # cecum widest
    vol.tube(field, colon, COLON_RADIUS * taper * haustra, k=0.01)
    sweep(jittered(APPENDIX, 0.004), np.array([0.012, 0.01, 0.009]), k=0.01)
    return vol.to_mesh(field)


def _coil_path(rng: np.random.Generator) -> np.ndarray:
    """Control points of the small intestine: a random Hamiltonian path through a 3D lattice.

    The path starts at the upper-left front corner (next to the duodenojejunal flexure) and is
    randomised by backbite moves on its free end, stopping once that end sits at the lower right,
    beside the cecum. Visiting every lattice node once keeps loops apart by a lattice step.
    """
    nx, ny, nz = COIL_NODES
    # Boustrophedon start: a valid Hamiltonian path beginning at (nx-1, ny-1, nz-1).
    path = []
    for k, iz in enumerate(range(nz - 1, -1, -1)):
        rows = range(ny - 1, -1, -1) if k % 2 == 0 else range(ny)
        for j, iy in enumerate(rows):
            cols = range(nx - 1, -1, -1) if (j + k * ny) % 2 == 0 else range(nx)
            path.extend((ix, iy, iz) for ix in cols)
    n = len(path)
    min_moves = 30 * n
    for move in range(200 * n):
        end = path[-1]
        if move >= min_moves and end[0] == 0 and end[1] <= 1:
            break
        axis, sign = rng.integers(3), rng.choice((-1, 1))
        w = list(end)
        w[axis] += sign
        w = tuple(w)
        if not all(0 <= c < m for c, m in zip(w, COIL_NODES, strict=True)) or w == path[-2]:
            continue
        i = path.index(w)
        path[i + 1 :] = path[i + 1 :][::-1]  # backbite: link the end to w, reverse the loose tail
    lo, hi = (np.asarray(b) for b in COIL_BOX)
    nodes = lo + np.asarray(path, dtype=np.float64) / (np.asarray(COIL_NODES) - 1) * (hi - lo)
    spacing = np.min((hi - lo) / (np.asarray(COIL_NODES) - 1))
    # A smooth random warp makes rows and columns wavy (neighbours bend alike, so gaps keep);
    # independent jitter then roughens each loop.
    phase = rng.uniform(0.0, 2 * np.pi, 3)
    freq = 2 * np.pi / (3.5 * spacing)
    x, y = nodes[:, 0], nodes[:, 1]
    warp = 0.3 * spacing * np.sin(np.stack([freq * y, freq * x, freq * (x + y)], axis=1) + phase)
    return nodes + warp + rng.normal(0.0, 0.08 * spacing, nodes.shape)
