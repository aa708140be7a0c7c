"""gicore.sessions: seeded user sessions over a scene's navigable space, on the clients' path code."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gicore.paths import light_position, path_views
from gicore.scene import SceneSpec, load_scene
from gicore.sessions import ORBIT_FRAMES_RANGE, navigable_views, plan_sessions, session_views


def _envelope(spec: SceneSpec) -> tuple[tuple[float, float], tuple[float, float]]:
    """(radius, height) ranges of the navigable space."""
    c = spec.camera
    radius = (c.radius * (1 - c.wobble), c.radius * (1 + c.wobble))
    return radius, (c.height * (1 - c.wobble), c.height * (1 + c.wobble))


def test_plans_are_seeded_and_users_take_turns() -> None:
    spec = load_scene("lung_plane")
    plan = plan_sessions(spec, 40, 4, 100, seed=7)
    assert plan == plan_sessions(spec, 40, 4, 100, seed=7)
    assert plan != plan_sessions(spec, 40, 4, 100, seed=8)
    assert [s.user for s in plan] == [k % 4 for k in range(40)] and [s.index for s in plan] == list(range(40))
    assert {s.kind for s in plan} == {"fly", "orbit"}
    assert len({s.light_offset for s in plan}) == 40  # the moving light: each session its own light state
    assert all(ORBIT_FRAMES_RANGE[0] <= s.orbit_frames <= ORBIT_FRAMES_RANGE[1] for s in plan)
    (r_lo, r_hi), (h_lo, h_hi) = _envelope(spec)
    for s in plan:
        assert r_lo - 1e-9 <= s.radius <= r_hi + 1e-9 and h_lo - 1e-9 <= s.height <= h_hi + 1e-9
    # a user's orbits stay near their habit: one user's spread is below the population's
    orbits = [s for s in plan_sessions(spec, 400, 8, 10, seed=1) if s.kind == "orbit"]
    by_user = [np.std([s.radius for s in orbits if s.user == u]) for u in range(8)]
    assert np.median(by_user) < np.std([s.radius for s in orbits])
    static = load_scene("lung_plane").model_copy(
        update={"light": spec.light.model_copy(update={"amplitude": (0.0, 0.0)})}
    )
    assert {s.light_offset for s in plan_sessions(static, 10, 2, 10)} == {0}


def test_fly_sessions_are_the_clients_path_and_orbits_keep_radius_and_height() -> None:
    spec = load_scene("lung_plane")
    plan = plan_sessions(spec, 30, 3, 120, seed=2)
    fly = next(s for s in plan if s.kind == "fly")
    views = session_views(spec, fly, 90.0, 32)
    expected = path_views(spec, 120, fly.orbit_frames, fly.seed, 90.0, 32)
    assert len(views) == 120
    assert [c.origin for c, _ in views] == [c.origin for c, _ in expected]
    assert [light for _, light in views] == [light_position(spec, fly.light_offset + f) for f in range(120)]
    orbit = next(s for s in plan if s.kind == "orbit")
    tx, _, tz = spec.camera.target
    for cam, _ in session_views(spec, orbit, 90.0, 32):
        assert math.hypot(cam.origin[0] - tx, cam.origin[2] - tz) == pytest.approx(orbit.radius)
        assert cam.origin[1] == pytest.approx(orbit.height) and cam.target == spec.camera.target
        assert cam.fov == 90.0 and cam.width == 32


def test_navigable_views_fill_the_envelope_and_the_arc() -> None:
    spec = load_scene("lung_cornell")  # a 70° arc through the box's open side
    c = spec.camera
    pairs = navigable_views(spec, 2000, seed=0)
    eyes = np.array([e for e, _ in pairs])
    radius = np.hypot(eyes[:, 0] - c.target[0], eyes[:, 2] - c.target[2])
    azimuth = np.degrees(np.arctan2(eyes[:, 0] - c.target[0], eyes[:, 2] - c.target[2]))
    (r_lo, r_hi), (h_lo, h_hi) = _envelope(spec)
    assert r_lo <= radius.min() and radius.max() <= r_hi and h_lo <= eyes[:, 1].min() and eyes[:, 1].max() <= h_hi
    assert np.abs(azimuth - c.azimuth_center).max() <= c.azimuth_range / 2
    assert np.ptp(azimuth) > 0.9 * c.azimuth_range and np.ptp(radius) > 0.9 * (r_hi - r_lo)
    assert navigable_views(spec, 50, seed=1) == navigable_views(spec, 50, seed=1)


@pytest.mark.parametrize(("sessions", "users", "frames"), [(0, 1, 10), (3, 0, 10), (3, 1, 0)])
def test_plan_rejects_empty_counts(sessions: int, users: int, frames: int) -> None:
    with pytest.raises(ValueError, match=">= 1"):
        plan_sessions(load_scene("lung_plane"), sessions, users, frames)
