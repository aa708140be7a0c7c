"""Procedural arterial tree: an aortic trunk branching recursively under Murray's law.

Modelled parts (patient's left on +x, anterior +z, y up, about one unit tall):
- the ascending aorta, the aortic arch running from the patient's right to left and back, and the
  descending aorta;
- three supra-aortic trees leaving the arch upwards (brachiocephalic, left common carotid, left
  subclavian), each branching for 3 generations;
- the aortic bifurcation into the common iliac arteries, each branching downwards for 6 generations.

Every bifurcation obeys Murray's law, r_parent^3 = r_child1^3 + r_child2^3: a seeded flow split
lambda in [0.3, 0.7] gives r1 = r * lambda^(1/3) and r2 = r * (1 - lambda)^(1/3). Branching angles
follow Murray's minimum-work optimum, cos(theta1) = (r^4 + r1^4 - r2^4) / (2 r^2 r1^2), plus seeded
jitter, and each generation's branching plane is rolled about 90 degrees from its parent's so the
tree fills space. Branch lengths scale with radius. Segments are capsules with a slight taper
inside a branch; radii are floored at one voxel so the finest branches stay connected at low detail.

Parameters: `seed` drives flow splits, angles, roll and bends; `detail` scales the grid resolution
(voxel = 0.0062 / detail units).
"""

from __future__ import annotations

import numpy as np

from gicore.anatomy.curves import catmull_rom, resample
from gicore.anatomy.sdf import Volume
from gicore.mesh import Mesh

BASE_VOXEL = 0.0062
AORTA_RADIUS = 0.042
# Arch branches: (fraction of the arch path where it leaves, radius, initial direction).
ARCH_BRANCHES = (
    (0.40, 0.021, (-0.45, 1.0, 0.1)),  # brachiocephalic
    (0.50, 0.015, (0.0, 1.0, 0.0)),  # left common carotid
    (0.60, 0.016, (0.5, 1.0, -0.1)),  # left subclavian
)
AORTA = (
    (-0.045, 0.66, 0.06),
    (-0.05, 0.84, 0.05),
    (-0.01, 0.93, 0.0),
    (0.04, 0.87, -0.05),
    (0.035, 0.72, -0.06),
    (0.02, 0.55, -0.05),
    (0.0, 0.44, -0.04),
)
ILIAC_GENERATIONS = 6
ARCH_GENERATIONS = 3
LENGTH_PER_RADIUS = 7.0
TAPER = 0.95  # radius at a branch's end relative to its start
SAMPLE_STEP = 0.008  # spacing of tube centre-line samples, independent of detail


Segment = tuple[np.ndarray, np.ndarray]  # (points (K, 3), radii (K,)) of one swept branch


def build_vessels(seed: int, detail: float) -> Mesh:
    """The arterial tree as one watertight mesh in generation units (not normalized)."""
    rng = np.random.default_rng(seed)
    voxel = BASE_VOXEL / detail
    control = np.asarray(AORTA) + rng.normal(0.0, 0.005, (len(AORTA), 3))
    aorta, s = resample(catmull_rom(control), SAMPLE_STEP)
    # Murray's law at the arch: what leaves through the branches no longer flows down the aorta.
    r_descending = (AORTA_RADIUS**3 - sum(r**3 for _, r, _ in ARCH_BRANCHES)) ** (1 / 3)
    arch_end = np.interp(ARCH_BRANCHES[-1][0], [0, 1], [0, s[-1]])
    aorta_radii = np.interp(s, [0.0, arch_end, s[-1]], [AORTA_RADIUS, r_descending, r_descending * TAPER])
    branches: list[Segment] = [(aorta, aorta_radii)]

    for fraction, radius, direction in ARCH_BRANCHES:
        origin = aorta[int(round(fraction * (len(aorta) - 1)))]
        _grow(
            rng,
            branches,
            origin,
            np.asarray(direction, float),
            radius,
            ARCH_GENERATIONS,
            bias=np.array((0.0, 0.6, 0.0)),
            roll=rng.uniform(0, np.pi),
        )
    # The aortic bifurcation is the first Murray split of the lower tree.
    _split(
        rng,
        branches,
        aorta[-1],
        aorta[-1] - aorta[-4],
        aorta_radii[-1],
        ILIAC_GENERATIONS,
        bias=np.array((0.0, -0.35, 0.0)),
        roll=np.pi / 2 + rng.normal(0.0, 0.1),
    )

    points = np.vstack([p for p, _ in branches])
    lo, hi = points.min(axis=0) - AORTA_RADIUS, points.max(axis=0) + AORTA_RADIUS
    vol = Volume(lo, hi, voxel, band=0.03)
    field = vol.empty()
    for path, radii in branches:
        vol.tube(field, path, np.maximum(radii, voxel))
    return vol.to_mesh(field)


def _grow(
    rng: np.random.Generator,
    branches: list[Segment],
    start: np.ndarray,
    direction: np.ndarray,
    radius: float,
    generations: int,
    bias: np.ndarray,
    roll: float,
) -> None:
    """Add one gently bent branch from `start`, then split its end unless no generations remain."""
    direction = direction / np.linalg.norm(direction)
    length = LENGTH_PER_RADIUS * radius * rng.uniform(0.85, 1.15) + 0.02
    bend = np.cross(direction, rng.normal(size=3))
    bend *= 0.08 * length / max(np.linalg.norm(bend), 1e-9)
    end = start + direction * length
    control = np.array([start, (start + end) / 2 + bend, end])
    path, s = resample(catmull_rom(control, 8), SAMPLE_STEP)
    branches.append((path, radius * (1 + (TAPER - 1) * s / s[-1])))
    if generations > 0:
        _split(rng, branches, end, path[-1] - path[-3], radius * TAPER, generations, bias, roll)


def _split(
    rng: np.random.Generator,
    branches: list[Segment],
    at: np.ndarray,
    parent_direction: np.ndarray,
    radius: float,
    generations: int,
    bias: np.ndarray,
    roll: float,
) -> None:
    """A Murray bifurcation at `at`: two children whose radii and angles obey Murray's laws."""
    d = parent_direction / np.linalg.norm(parent_direction)
    flow = rng.uniform(0.3, 0.7)
    r1, r2 = radius * flow ** (1 / 3), radius * (1 - flow) ** (1 / 3)
    # The branching plane holds the parent axis and `side`, rolled about the axis by `roll`.
    helper = np.array((1.0, 0.0, 0.0)) if abs(d[0]) < 0.9 else np.array((0.0, 0.0, 1.0))
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    side = np.cos(roll) * u + np.sin(roll) * np.cross(d, u)
    for r_child, r_other, sign in ((r1, r2, 1.0), (r2, r1, -1.0)):
        cos_theta = (radius**4 + r_child**4 - r_other**4) / (2 * radius**2 * r_child**2)
        theta = np.arccos(np.clip(cos_theta, -1.0, 1.0)) + rng.normal(0.0, 0.12)
        child = np.cos(theta) * d + sign * np.sin(theta) * side + bias
        _grow(rng, branches, at, child, r_child, generations - 1, bias, roll + np.pi / 2 + rng.normal(0.0, 0.4))
