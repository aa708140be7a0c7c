"""Camera fly-throughs and light schedules derived from a scene spec (docs/architecture.md, Scenes).

Both are pure functions of (spec, frame index or count, seed), so any frame can be regenerated alone
(resumable datasets, servers rendering a requested frame). The camera orbit is smooth: azimuth advances
linearly over the path while radius and height wobble with two seeded low-frequency sinusoids.
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from gicore.camera import Camera
from gicore.scene import SceneSpec


def frame_seed(seed: int, purpose: str, frame: int) -> int:
    """An independent, reproducible render seed per (run seed, purpose, frame): same inputs, same noise;
    any change, independent noise. ``purpose`` names the render (e.g. ``"di"``, ``"gt"``, a dataset split)."""
    return zlib.crc32(f"{seed}/{purpose}/{frame}".encode())


def light_position(spec: SceneSpec, frame: int) -> tuple[float, float, float]:
    """The light's position at ``frame``: rest position plus sinusoidal motion along x and y."""
    light = spec.light
    x, y, z = light.position
    ax, ay = light.amplitude
    px, py = light.period
    return (x + ax * math.sin(2 * math.pi * frame / px), y + ay * math.sin(2 * math.pi * frame / py), z)


def light_range(spec: SceneSpec) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Corners of the box the light of ``spec`` sweeps (:func:`light_position`): rest ± amplitude in x and y;
    the rest point for a static light."""
    (x, y, z), (ax, ay) = spec.light.position, spec.light.amplitude
    return (x - abs(ax), y - abs(ay), z), (x + abs(ax), y + abs(ay), z)


def camera_path(
    spec: SceneSpec, n_frames: int, seed: int = 0, fov: float | None = None, resolution: int | None = None
) -> list[Camera]:
    """``n_frames`` cameras of a smooth fly-through; ``fov`` defaults to the spec's GI-camera FOV.

    Different seeds give different (but equally smooth) trajectories: the start azimuth and the wobble
    phases are seeded, so a validation path with another seed is held out from the training path.
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    c = spec.camera
    rng = np.random.default_rng(seed)
    start = rng.uniform(0.0, 1.0)
    phases = rng.uniform(0.0, 2 * math.pi, size=4)
    res = spec.resolution if resolution is None else resolution
    cams = []
    for i in range(n_frames):
        t = i / max(n_frames, 1)
        if c.azimuth_range >= 360.0:
            az = 360.0 * (start + t)
        else:  # sweep back and forth across the allowed arc (Cornell box: through the open side)
            az = c.azimuth_center + 0.5 * c.azimuth_range * math.sin(2 * math.pi * (start + t))
        radius = c.radius * (1.0 + c.wobble * math.sin(2 * math.pi * 2 * t + phases[0]))
        height = c.height * (1.0 + c.wobble * math.sin(2 * math.pi * 3 * t + phases[1]))
        a = math.radians(az)
        origin = (c.target[0] + radius * math.sin(a), height, c.target[2] + radius * math.cos(a))
        wob = 0.1 * c.wobble
        target = (
            c.target[0] + wob * math.sin(2 * math.pi * 2 * t + phases[2]),
            c.target[1] + wob * math.sin(2 * math.pi * 3 * t + phases[3]),
            c.target[2],
        )
        cams.append(
            Camera(origin, target, fov=c.gi_fov if fov is None else fov, near=c.near, far=c.far, width=res, height=res)
        )
    return cams
