"""Seeded user sessions over a scene's navigable space: what a server's GI tree sees from many visits.

A scene's *navigable space* is what its camera spec lets a client reach: eyes around ``target`` at radius
``radius * (1 ± wobble)`` and height ``height * (1 ± wobble)``, within the spec's azimuth arc, looking at
the target. A *session* is one visit of ``frames`` frames, as the clients fly it
(:func:`gicore.paths.path_views`: a lap of ``orbit_frames`` frames, repeated), of one of two kinds:

- ``fly``: the scene's own fly-through (:func:`gicore.paths.camera_path`) under the session's seed (start
  azimuth and wobble phases);
- ``orbit``: a steady orbit (no wobble) at a radius and height inside the envelope above.

Speed (``orbit_frames``) varies per session. For a scene whose light moves, each session starts at its own
frame of the light's schedule (:func:`gicore.paths.light_position`), so sessions see different light states;
a static light stays at rest.

Users: sessions come from ``users`` users in turn (session ``k`` is user ``k mod users``'s). Each user has
a seeded habit: how often they orbit rather than fly, where in the envelope they orbit and how fast they go;
their sessions scatter around it. One user thus revisits one region; many users cover more of the space.
Everything is a pure function of (spec, counts, seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from gicore.camera import Camera
from gicore.paths import Light, light_position, path_views
from gicore.scene import SceneSpec

Vec3 = tuple[float, float, float]
SessionKind = Literal["fly", "orbit"]
#: Fastest and slowest lap a session flies, frames per full path (the clients' default lap is 300 frames).
ORBIT_FRAMES_RANGE = (300, 3000)
#: Spread of a user's sessions around their habit: fraction of the envelope (position) and of a log lap.
HABIT_SPREAD = 0.15


@dataclass(frozen=True)
class Session:
    """One visit (see the module docstring)."""

    #: Index of the session, in the order the tree sees them.
    index: int
    user: int
    kind: SessionKind
    #: Seed of the camera path (start azimuth, wobble phases).
    seed: int
    frames: int
    #: Frames per lap of the path: the session's speed.
    orbit_frames: int
    #: Orbit radius and height (a ``fly`` session wobbles around the spec's own).
    radius: float
    height: float
    #: The light schedule's frame at the session's first frame (0 for a static light).
    light_offset: int


def plan_sessions(spec: SceneSpec, sessions: int, users: int, frames: int, seed: int = 0) -> list[Session]:
    """``sessions`` visits of ``frames`` frames by ``users`` users, in the order they reach the server."""
    if sessions < 1 or users < 1 or frames < 1:
        raise ValueError(f"sessions, users and frames must be >= 1, got {sessions}, {users}, {frames}")
    c = spec.camera
    rng = np.random.default_rng([seed, 23])
    lo, hi = (math.log(f) for f in ORBIT_FRAMES_RANGE)
    # per user: P(orbit), home (radius, height) as fractions of the envelope, home log lap
    habits = [(rng.uniform(), rng.uniform(size=2), rng.uniform(lo, hi)) for _ in range(users)]
    out = []
    for k in range(sessions):
        user = k % users
        p_orbit, home, log_lap = habits[user]
        kind: SessionKind = "orbit" if rng.uniform() < p_orbit else "fly"
        r_frac, h_frac = np.clip(home + rng.normal(0.0, HABIT_SPREAD, 2), 0.0, 1.0)
        lap = int(round(math.exp(np.clip(log_lap + rng.normal(0.0, HABIT_SPREAD * (hi - lo)), lo, hi))))
        orbit = kind == "orbit"
        out.append(
            Session(
                index=k,
                user=user,
                kind=kind,
                seed=int(rng.integers(0, 2**31)),
                frames=frames,
                orbit_frames=lap,
                radius=c.radius * (1.0 + c.wobble * (2.0 * r_frac - 1.0)) if orbit else c.radius,
                height=c.height * (1.0 + c.wobble * (2.0 * h_frac - 1.0)) if orbit else c.height,
                light_offset=int(rng.integers(0, 1_000_000)) if spec.light.moves else 0,
            )
        )
    return out


def session_views(spec: SceneSpec, session: Session, fov: float, resolution: int) -> list[tuple[Camera, Light]]:
    """(GI camera, light) of each frame of ``session``: the clients' path code on the session's spec."""
    path_spec = spec
    if session.kind == "orbit":
        camera = spec.camera.model_copy(update={"radius": session.radius, "height": session.height, "wobble": 0.0})
        path_spec = spec.model_copy(update={"camera": camera})
    views = path_views(path_spec, session.frames, session.orbit_frames, session.seed, fov, resolution)
    return [(cam, light_position(spec, session.light_offset + f)) for f, (cam, _) in enumerate(views)]


def navigable_views(spec: SceneSpec, n: int, seed: int = 0) -> list[tuple[Vec3, Vec3]]:
    """``n`` (eye, target) pairs drawn uniformly from the navigable space (module docstring): radius, height
    and azimuth uniform within the envelope and the arc, the target moved within the path's target wobble."""
    c = spec.camera
    rng = np.random.default_rng([seed, 24])
    radius = c.radius * (1.0 + c.wobble * rng.uniform(-1.0, 1.0, n))
    height = c.height * (1.0 + c.wobble * rng.uniform(-1.0, 1.0, n))
    if c.azimuth_range >= 360.0:
        azimuth = rng.uniform(0.0, 360.0, n)
    else:
        azimuth = c.azimuth_center + c.azimuth_range * rng.uniform(-0.5, 0.5, n)
    a = np.radians(azimuth)
    tx, ty, tz = c.target
    wob = 0.1 * c.wobble  # camera_path's target wobble
    dx, dy = wob * rng.uniform(-1.0, 1.0, (2, n))
    eyes = np.stack([tx + radius * np.sin(a), height, tz + radius * np.cos(a)], axis=1)
    targets = np.stack([tx + dx, ty + dy, np.full(n, tz)], axis=1)
    return [(tuple(map(float, e)), tuple(map(float, t))) for e, t in zip(eyes, targets, strict=True)]
