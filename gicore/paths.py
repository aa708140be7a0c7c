"""Camera fly-throughs, light schedules and the space they move in, derived from a scene spec
(docs/architecture.md, Scenes).

Paths are pure functions of (spec, frame index or count, seed), so any frame can be regenerated alone
(resumable datasets, servers rendering a requested frame). The camera orbit is smooth: azimuth advances
linearly over the path while radius and height wobble with two seeded low-frequency sinusoids.
:func:`navigation` is the envelope those orbits stay in and :func:`light_bounds` the box a light may take:
what a served or recorded camera and light are checked against.
"""

from __future__ import annotations

import math
import zlib
from typing import Any

import numpy as np

from gicore.camera import Camera
from gicore.scene import SceneSpec

Vec3 = tuple[float, float, float]
#: A point light's position (:func:`light_position`).
Light = Vec3
#: Default light-cell side, scene units: the paper scenes' lights sweep ±0.6 to ±1 along x, so 4 to 8 cells.
DEFAULT_LIGHT_CELL = 0.25
#: The fly-through's look-at target moves up to this fraction of the wobble from the spec's target, in x and y.
TARGET_WOBBLE = 0.1


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


def light_bounds(spec: SceneSpec, margin: float = DEFAULT_LIGHT_CELL) -> tuple[Vec3, Vec3]:
    """Corners of the box a requested light must lie in: a moving light's range widened by ``margin`` on every
    side (a light cell: the cells its sweep touches), a static light's rest point."""
    low, high = light_range(spec)
    if not spec.light.moves:
        return low, high
    return tuple(c - margin for c in low), tuple(c + margin for c in high)  # type: ignore[return-value]


def navigation(spec: SceneSpec) -> dict[str, Any]:
    """The envelope the fly-throughs of ``spec`` (:func:`camera_path`) keep the eye in, as JSON data: the
    look-at ``target`` and how far the path moves it in x and y (``target_wobble``), the eye's horizontal
    distance from the target (``radius``) and height (``height``) as [lo, hi], and its azimuth (degrees,
    ``atan2(x - tx, z - tz)``) as [lo, hi], or None for the full circle."""
    c = spec.camera
    arc = c.azimuth_range >= 360.0
    return {
        "target": [float(v) for v in c.target],
        "target_wobble": TARGET_WOBBLE * c.wobble,
        "radius": [c.radius * (1.0 - c.wobble), c.radius * (1.0 + c.wobble)],
        "height": sorted([c.height * (1.0 - c.wobble), c.height * (1.0 + c.wobble)]),
        "azimuth": None if arc else [c.azimuth_center - c.azimuth_range / 2, c.azimuth_center + c.azimuth_range / 2],
    }


def outside_navigation(nav: dict[str, Any], eye: Vec3, margin: float) -> str | None:
    """What puts ``eye`` outside the envelope ``nav`` (:func:`navigation`) widened by ``margin`` scene units
    (the azimuth arc by the angle ``margin`` spans at the inner radius); None when it is inside."""
    tx, _, tz = nav["target"]
    dx, dz = eye[0] - tx, eye[2] - tz
    checks = [("radius", math.hypot(dx, dz), nav["radius"], margin), ("height", eye[1], nav["height"], margin)]
    for name, value, (lo, hi), slack in checks:
        if not lo - slack <= value <= hi + slack:
            return f"its {name} {value:.4g} is outside [{lo:.4g}, {hi:.4g}]"
    if nav["azimuth"] is not None:
        lo, hi = nav["azimuth"]
        slack = math.degrees(margin / max(nav["radius"][0], 1e-9))
        azimuth = math.degrees(math.atan2(dx, dz))
        past = (azimuth - lo) % 360.0  # degrees past the arc's start, going round
        if not (past <= hi - lo + slack or past >= 360.0 - slack):
            return f"its azimuth {azimuth:.4g}° is outside [{lo:.4g}°, {hi:.4g}°]"
    return None


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
        wob = TARGET_WOBBLE * c.wobble
        target = (
            c.target[0] + wob * math.sin(2 * math.pi * 2 * t + phases[2]),
            c.target[1] + wob * math.sin(2 * math.pi * 3 * t + phases[3]),
            c.target[2],
        )
        cams.append(
            Camera(origin, target, fov=c.gi_fov if fov is None else fov, near=c.near, far=c.far, width=res, height=res)
        )
    return cams


def path_views(
    spec: SceneSpec, frames: int, orbit_frames: int, seed: int, fov: float, resolution: int
) -> list[tuple[Camera, Light]]:
    """(local camera, light) of each frame of a client run: the scene's fly-through with ``orbit_frames`` frames
    per orbit (repeating), FOV ``fov``, and the light's schedule."""
    cams = camera_path(spec, orbit_frames, seed=seed, fov=fov, resolution=resolution)
    return [(cams[f % orbit_frames], light_position(spec, f)) for f in range(frames)]
