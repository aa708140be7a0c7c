"""How the GI tree grows under user sessions (baseline_cloudbaking.growth): filled by the store's own lookup rule,
as a real GI tree fills; its saturation and the session that passes a size."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from baseline_cloudbaking.growth import capacity, fill_sessions, first_session_over, saturation_session, session_frames
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree
from baseline_cloudbaking.viewpoints import MapKey, Tolerance, light_cell
from gicore.scene import SceneSpec, load_scene
from gicore.sessions import plan_sessions

#: Δ 0: every distinct (viewpoint, light cell) is its own entry (the paper's accounting).
EXACT = Tolerance(0.0, 0.0)


def _tiny_space() -> SceneSpec:
    """lung_plane reduced to one orbit over a 20° arc under a static light: a space a few maps cover."""
    spec = load_scene("lung_plane")
    camera = spec.camera.model_copy(update={"wobble": 0.0, "azimuth_range": 20.0})
    light = spec.light.model_copy(update={"amplitude": (0.0, 0.0)})
    return spec.model_copy(update={"camera": camera, "light": light})


def test_growth_is_monotone_and_counts_what_a_real_store_stores(tmp_path: Path) -> None:
    spec = load_scene("lung_plane")
    plan = plan_sessions(spec, 5, 2, 60, seed=3)
    run = session_frames(spec, plan, DEFAULT_LIGHT_CELL, spec.camera.gi_fov)
    tol = Tolerance(0.05, 2.0)
    fills = {t: fill_sessions(run, t) for t in (EXACT, tol, Tolerance(0.2, 10.0))}
    for fill in fills.values():
        assert np.all(np.diff(fill.entries) >= 0) and fill.entries[-1] == len(fill.creators)
        assert np.all(fill.entries <= run.ends)  # never more entries than frames seen
    # a looser tolerance never stores more; Δ 0 stores every distinct (viewpoint, light cell)
    assert np.all(fills[Tolerance(0.2, 10.0)].entries <= fills[tol].entries)
    assert np.all(fills[tol].entries <= fills[EXACT].entries)
    assert fills[EXACT].entries[-1] == len(set(zip(run.views, run.cells, strict=True)))
    assert fills[tol].entries[-1] < fills[EXACT].entries[-1]
    # the same frames through a real GI tree (find, insert on a miss) store the same number of maps
    with GITree(tmp_path / "store", tolerance=tol) as tree:
        tree.register_scene("lung_plane", "sha", DEFAULT_LIGHT_CELL)
        for i, ((cam, light), view) in enumerate(zip(run.frames, run.views, strict=True)):
            key = MapKey("lung_plane", light_cell(light, DEFAULT_LIGHT_CELL), 16, cam.fov, "jpeg", 1, False)
            if tree.find(key, view) is None:
                tree.insert(key, view, i.to_bytes(4, "little"))
        assert tree.stats()["entries"] == fills[tol].entries[-1]


def test_saturation_is_detected_on_a_tiny_space_and_not_on_a_growing_one() -> None:
    spec = _tiny_space()
    plan = plan_sessions(spec, 12, 2, 200, seed=0)
    fill = fill_sessions(session_frames(spec, plan, DEFAULT_LIGHT_CELL, spec.camera.gi_fov), Tolerance())
    k = saturation_session(fill.entries, 200, 0.01)
    assert k is not None and k <= 6, fill.entries
    assert fill.entries[-1] - fill.entries[k - 1] <= 0.01 * 200 * (12 - k)
    level = capacity(spec, Tolerance(), DEFAULT_LIGHT_CELL, 3000, seed=0)
    assert level["light_cells"] == 1 and level["last_tenth_miss_rate"] == 0.0
    # the sessions' tree and the uniform cover agree on the space's size within a factor of 2
    assert 0.5 <= fill.entries[-1] / level["entries"] <= 2.0
    # the rule itself: a plateau after session 3; steady growth never saturates; a late jump moves the point
    assert saturation_session(np.array([50, 90, 100, 100, 101, 101, 101, 101, 101, 101]), 100, 0.01) == 3
    assert saturation_session(np.arange(1, 21) * 30, 100, 0.01) is None
    assert saturation_session(np.array([50, 50, 50, 50, 50, 50, 50, 80, 80, 80]), 100, 0.01) == 8
    assert saturation_session(np.array([50, 50, 50, 50, 50, 50, 50, 50, 50, 80]), 100, 0.01) is None


def test_crossover_is_the_first_session_past_the_limit() -> None:
    entries = np.array([100, 250, 400, 480])
    assert first_session_over(entries, 10_000.0, 3_000_000.0) == 3  # 4.0 MB > 3 MB
    assert first_session_over(entries, 10_000.0, 5_000_000.0) is None
    assert first_session_over(entries, 10_000.0, 0.0) == 1
