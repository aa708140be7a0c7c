"""A scene's configuration space (``cloudbaking-prebake --space all``): its grid serves every view of the
camera's envelope and of any fly-through within the tolerance, its light states hold every light cell the
schedule reaches, an uncoverable tolerance is refused in one line, and a baked space serves a later
fly-through without a single new map."""

from __future__ import annotations

import math
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from baseline_cloudbaking.bake import SPACE_VIEWS_MAX, configuration_space, fly_through, light_states
from baseline_cloudbaking.prebake_cli import PrebakeConfig, prebake_scene
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree
from baseline_cloudbaking.viewpoints import Tolerance, Viewpoint, light_cell, nearest
from gicore.paths import light_position
from gicore.scene import SceneSpec, load_scene
from tests.helpers.cloud import BIN, write_scenes


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("space_scenes"))


def worst_served(space_views: list[Viewpoint], views: list[Viewpoint], tol: Tolerance) -> int:
    """How many of ``views`` no grid view serves within ``tol``."""
    eyes = np.array([v.eye for v in space_views])
    dirs = np.array([v.direction for v in space_views])
    return sum(nearest(eyes, dirs, view, tol) is None for view in views)


@pytest.mark.parametrize(("scene", "tol"), [("lung_cornell", Tolerance(0.1, 4.0)), ("lung_plane", Tolerance(0.2, 6.0))])
def test_the_grid_serves_every_view_of_the_envelope_and_of_any_fly_through(scene: str, tol: Tolerance) -> None:
    spec = load_scene(scene)
    space = configuration_space(spec, tol, DEFAULT_LIGHT_CELL)
    grid_views = space.views()
    # Fly-throughs under other seeds than any prebake used, at the default and a coarse frame count.
    flown = [f.view for seed in (0, 7, 1234) for f in fly_through(spec, 400, 16, DEFAULT_LIGHT_CELL, seed)]
    assert worst_served(grid_views, flown, tol) == 0
    # The grid's worst cases: the corners of its cells (farthest from every grid eye), looking at the target
    # moved to each corner of its wobble (farthest in angle).
    c = spec.camera
    arc = math.radians(min(c.azimuth_range, 360.0))
    a_lo = math.radians(c.azimuth_center) - arc / 2
    axes = [
        np.linspace(a_lo, a_lo + arc, space.grid[0] + 1),
        np.linspace(c.radius * (1 - c.wobble), c.radius * (1 + c.wobble), space.grid[1] + 1),
        np.linspace(c.height * (1 - c.wobble), c.height * (1 + c.wobble), space.grid[2] + 1),
    ]
    corners = [
        Viewpoint.look_at(
            (c.target[0] + r * math.sin(a), h, c.target[2] + r * math.cos(a)),
            (c.target[0] + sx * 0.1 * c.wobble, c.target[1] + sy * 0.1 * c.wobble, c.target[2]),
        )
        for a in axes[0]
        for r in axes[1]
        for h in axes[2]
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    assert worst_served(grid_views, corners, tol) == 0
    # Not wasteful: each grid axis holds at most one cell more than its extent over the cell side needs.
    side = 2 * space.cover / math.sqrt(3)
    extents = (c.radius * (1 + c.wobble) * arc, 2 * c.radius * c.wobble, 2 * abs(c.height) * c.wobble)
    assert all(cells <= extent / side + 1 for cells, extent in zip(space.grid, extents, strict=True)), space.grid
    assert space.cover > 0.5 * tol.position


def test_light_states_hold_every_cell_the_schedule_reaches() -> None:
    spec = load_scene("lung_plane")
    states = light_states(spec, DEFAULT_LIGHT_CELL)
    cells = [cell for cell, _ in states]
    assert len(cells) == len(set(cells)) == 45  # x: 2.0 / 0.25 -> 9 cells; y: 0.8 / 0.25 -> 5 cells
    assert all(light_cell(pos, DEFAULT_LIGHT_CELL) == cell for cell, pos in states)
    reached = {light_cell(light_position(spec, frame), DEFAULT_LIGHT_CELL) for frame in range(0, 200_000, 7)}
    assert reached <= set(cells)


def test_a_static_light_is_one_state(scenes: Path) -> None:
    spec = load_scene(scenes / "ball_static.json")
    assert light_states(spec, DEFAULT_LIGHT_CELL) == [(None, tuple(map(float, spec.light.position)))]


def test_an_uncoverable_tolerance_is_refused(scenes: Path) -> None:
    spec = load_scene("lung_plane")
    with pytest.raises(ValueError, match="above the target wobble"):
        configuration_space(spec, Tolerance(0.05, 0.5), DEFAULT_LIGHT_CELL)
    with pytest.raises(ValueError, match="Δp must be > 0"):
        configuration_space(spec, Tolerance(0.0, 2.0), DEFAULT_LIGHT_CELL)
    with pytest.raises(ValueError, match=f"more than {SPACE_VIEWS_MAX:,}"):
        configuration_space(spec, Tolerance(0.001, 2.0), DEFAULT_LIGHT_CELL)
    argv = [str(BIN / "cloudbaking-prebake"), "lung_plane", "--store", str(scenes / "s"), "--space", "all"]
    proc = subprocess.run([*argv, "--tolerance-deg", "0.5"], capture_output=True, text=True, timeout=60)
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(errors) == 1 and "--tolerance-deg" in errors[0], proc.stderr
    assert not (scenes / "s").exists()


def test_a_baked_space_serves_a_later_fly_through_without_a_new_map(scenes: Path, tmp_path: Path) -> None:
    spec: SceneSpec = load_scene(scenes / "ball_moving.json")
    cfg = PrebakeConfig(resolution=16, spp=1, tolerance=Tolerance(1.0, 30.0), light_cell=10.0, space="all")
    baked = prebake_scene(tmp_path, "ball_moving", spec, cfg, progress=False)
    assert (baked.frames, baked.served, baked.baked) == (6, 6, 6)
    for seed in (0, 99):
        path_cfg = replace(cfg, space="fly-through", frames=300, seed=seed)
        flown = prebake_scene(tmp_path, "ball_moving", spec, path_cfg, progress=False)
        assert (flown.served, flown.baked) == (300, 0)
    with GITree(tmp_path) as tree:
        assert len(tree.entries()) == 6
