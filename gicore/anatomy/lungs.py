"""Procedural lungs with trachea and bronchi.

Modelled parts (patient's right lung on -x, anterior is +z, y up, about one unit tall):
- right lung: upper, middle and lower lobes; left lung: upper lobe with lingula and lower lobe. Each
  lobe is a tilted ellipsoid; lobes of one lung are smoothly united with a narrow blend, so the
  fissures stay visible as grooves;
- a cardiac notch carved from the anterior, medial, lower part of the left lung, a domed diaphragm
  carved from both bases and a mediastinal gap that flattens the medial faces;
- a ringed trachea splitting at the carina into the right main bronchus (shorter, wider, steeper)
  and the left main bronchus (longer, more horizontal), each branching into lobar bronchi at the
  hilum.

Parameters: `seed` jitters lobe sizes, positions and tilts and the bronchial end points; `detail`
scales the grid resolution (voxel = 0.0085 / detail units), so triangle count grows as detail**2.
"""

from __future__ import annotations

import numpy as np

from gicore.anatomy.sdf import Volume, rotation, smooth_min
from gicore.mesh import Mesh

BASE_VOXEL = 0.0085
LOBE_BLEND = 0.045  # narrow enough to leave the fissures as grooves
AIRWAY_BLEND = 0.015

# (centre, radii, tilt about x in radians: positive tips the top backwards, taper: negative is
# broader below). The lobes stack into a cone-like lung: narrow apex, broad base.
RIGHT_LOBES = {
    "upper": ((-0.18, 0.66, 0.01), (0.135, 0.22, 0.145), 0.2, -0.2),
    "middle": ((-0.225, 0.44, 0.045), (0.16, 0.13, 0.1), -0.35, -0.1),
    "lower": ((-0.21, 0.34, -0.04), (0.165, 0.28, 0.155), 0.3, -0.3),
}
LEFT_LOBES = {
    "upper": ((0.185, 0.63, 0.015), (0.135, 0.24, 0.145), 0.15, -0.2),
    "lingula": ((0.215, 0.43, 0.04), (0.13, 0.11, 0.09), -0.3, -0.1),
    "lower": ((0.205, 0.33, -0.04), (0.16, 0.275, 0.155), 0.3, -0.3),
}
CARINA = (0.0, 0.72, -0.03)


def build_lungs(seed: int, detail: float) -> Mesh:
    """Both lungs and the airways as one watertight mesh in generation units (not normalized)."""
    rng = np.random.default_rng(seed)
    vol = Volume((-0.40, 0.0, -0.25), (0.40, 1.10, 0.25), BASE_VOXEL / detail, band=0.06)

    lungs = vol.empty()
    for lobes in (RIGHT_LOBES, LEFT_LOBES):
        lung = vol.empty()
        for centre, radii, tilt, taper in lobes.values():
            vol.ellipsoid(
                lung,
                np.array(centre) + rng.normal(0.0, 0.008, 3),
                np.array(radii) * rng.uniform(0.94, 1.06, 3),
                rotation("x", tilt + rng.normal(0.0, 0.06)),
                k=LOBE_BLEND,
                taper=taper,
            )
        lungs = np.minimum(lungs, lung)  # the two lungs never touch: no blend needed
    notch = np.array((0.11, 0.13, 0.14)) * rng.uniform(0.9, 1.1)
    vol.ellipsoid(lungs, (0.06, 0.28, 0.1), notch, k=0.03, carve=True)  # cardiac notch
    for x, top in ((-0.2, 0.17), (0.2, 0.15)):  # diaphragm domes, the right one higher (liver)
        vol.ellipsoid(lungs, (x, top - 0.16, -0.01), (0.19, 0.16, 0.22), k=0.03, carve=True)
    vol.ellipsoid(lungs, (0.0, 0.45, 0.05), (0.085, 0.6, 0.3), k=0.03, carve=True)  # mediastinum

    airways = vol.empty()
    _trachea(vol, airways, rng)
    carina = np.array(CARINA)
    # (hilum, bronchus radii at its middle and end, upward arch of its middle, lobes it feeds)
    for hilum, radius, arch, lobes in (
        ((-0.125, 0.60, -0.035), (0.024, 0.02), 0.0, RIGHT_LOBES),
        ((0.135, 0.625, -0.035), (0.021, 0.018), 0.015, LEFT_LOBES),
    ):
        hilum = np.array(hilum) + rng.normal(0.0, 0.006, 3)
        mid = (carina + hilum) / 2 + (0.0, arch, 0.0)
        vol.tube(airways, np.array([carina, mid, hilum]), np.array([0.03, radius[0], radius[1]]))
        for centre, *_ in lobes.values():
            # Lobar bronchi run from the hilum halfway to each lobe centre, ending inside the lobe.
            end = hilum + 0.55 * (np.array(centre) - hilum) + rng.normal(0.0, 0.01, 3)
            vol.tube(airways, np.array([hilum, end]), np.array([radius[1] * 0.8, 0.011]))
    return vol.to_mesh(smooth_min(lungs, airways, AIRWAY_BLEND))


def _trachea(vol: Volume, field: np.ndarray, rng: np.random.Generator) -> None:
    """The trachea from the larynx down to the carina, its cartilage rings as a radius ripple."""
    top = np.array((0.0, 1.06, -0.02))
    n = 80
    s = np.linspace(0.0, 1.0, n)
    points = top + s[:, None] * (np.array(CARINA) - top)
    length = np.linalg.norm(np.array(CARINA) - top)
    period = 0.04 * rng.uniform(0.92, 1.08)
    radii = 0.032 * (1.0 + 0.07 * np.cos(2 * np.pi * s * length / period))
    vol.tube(field, points, radii)
