"""`bench storage`'s growth law: the GI tree under many sessions, filled by the store's own lookup rule."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from baseline_cloudbaking.bake import fly_through, gi_camera
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree
from baseline_cloudbaking.viewpoints import MapKey, Tolerance, light_cell
from bench.runner import build_config
from bench.storage_config import PAPER_TOLERANCE, RAW_CODEC, StorageConfig
from bench.storage_growth import (
    _growth_entry_bytes,
    capacity,
    fill_sessions,
    first_session_over,
    paper_accounting,
    saturation_session,
    session_frames,
)
from gicore.error_policy import UserError
from gicore.results import Results, read_rows
from gicore.scene import SceneSpec, load_scene
from gicore.sessions import plan_sessions

REPO = Path(__file__).resolve().parents[2]


def _tiny_space() -> SceneSpec:
    """lung_plane reduced to one orbit over a 20° arc under a static light: a space a few maps cover."""
    spec = load_scene("lung_plane")
    camera = spec.camera.model_copy(update={"wobble": 0.0, "azimuth_range": 20.0})
    light = spec.light.model_copy(update={"amplitude": (0.0, 0.0)})
    return spec.model_copy(update={"camera": camera, "light": light})


def test_paper_accounting_row_is_one_rgb8_map_per_frame_within_10_percent(tmp_path: Path) -> None:
    """A 1500-frame fly-through at 512²: the lookup rule at Δ 0 stores every frame, each an uncompressed RGB8 map of
    a real baked GI map; the row must lie within 10 % of 1500 × 512² × 3 B (the paper's lung: 1.15 GB)."""
    spec = load_scene("lung_plane")
    cfg = StorageConfig(
        scenes=("lung_plane",), frames=1500, resolutions=(512,), codecs=("jpeg",), spp=1, growth_samples=1,
        map_cache=tmp_path / "maps",
    )  # fmt: skip
    path = fly_through(spec, cfg.frames, 512, cfg.light_cell)
    creators = [(f.camera, f.light) for f in path[:1]]
    sizes = _growth_entry_bytes(cfg, spec, "lung_plane", creators, seed=0)
    store_entries = 277  # any count: only the paper row is checked here
    res = Results("storage", tmp_path, 0)
    paper_accounting(cfg, res, "lung_plane", path, store_entries, sizes)
    rows = read_rows(res.write())
    row = next(r for r in rows if r["metric"] == "accounting_bytes" and r["config"]["step"] == "paper")
    entries = next(r for r in rows if r["metric"] == "accounting_entries" and r["config"]["step"] == "paper")
    assert entries["value"] == 1500  # every frame of the path is its own entry at Δ 0
    assert row["value"] == pytest.approx(1500 * 512**2 * 3, rel=0.10)
    assert sizes[(512, RAW_CODEC)] == [512 * 512 * 3]
    assert abs(row["value"] / 1.15e9 - 1) < 0.10  # the paper's lung figure, reproduced
    tolerance = next(r for r in rows if r["metric"] == "accounting_bytes" and r["config"]["step"] == "tolerance")
    jpeg = next(r for r in rows if r["metric"] == "accounting_bytes" and r["config"]["codec"] == "jpeg")
    assert jpeg["value"] < tolerance["value"] < row["value"]  # the decomposition: tolerance, then the codec
    # the baked map is cached: a second call bakes nothing and measures the same bytes
    assert _growth_entry_bytes(cfg, spec, "lung_plane", creators, seed=0) == sizes
    assert len(list((tmp_path / "maps").glob("*.npz"))) == 1


def test_growth_is_monotone_and_counts_what_a_real_store_stores(tmp_path: Path) -> None:
    spec = load_scene("lung_plane")
    plan = plan_sessions(spec, 5, 2, 60, seed=3)
    run = session_frames(spec, plan, DEFAULT_LIGHT_CELL, spec.camera.gi_fov)
    tol = Tolerance(0.05, 2.0)
    fills = {t: fill_sessions(run, t) for t in (PAPER_TOLERANCE, tol, Tolerance(0.2, 10.0))}
    for fill in fills.values():
        assert np.all(np.diff(fill.entries) >= 0) and fill.entries[-1] == len(fill.creators)
        assert np.all(fill.entries <= run.ends)  # never more entries than frames seen
    # a looser tolerance never stores more; Δ 0 stores every distinct (viewpoint, light cell)
    assert np.all(fills[Tolerance(0.2, 10.0)].entries <= fills[tol].entries)
    assert np.all(fills[tol].entries <= fills[PAPER_TOLERANCE].entries)
    assert fills[PAPER_TOLERANCE].entries[-1] == len(set(zip(run.views, run.cells, strict=True)))
    assert fills[tol].entries[-1] < fills[PAPER_TOLERANCE].entries[-1]
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


@pytest.mark.parametrize(
    ("given", "culprit"),
    [
        ({"sessions": 0}, "--sessions = 0 is below 1"),
        ({"users": "2,0"}, "--users = 0 is below 1"),  # a tuple option arrives as its text
        ({"saturation_rate": 1.5}, "--saturation-rate = 1.5 is above 1.0"),
        ({"paper_resolution": 384}, "--paper-resolution 384 is not one of --resolutions 256,512"),
        ({"session_frames": 0}, "--session-frames = 0 is below 1"),
        ({"map_cache": REPO / "README.md"}, "--map-cache .*README.md is a file"),
    ],
)
def test_bad_growth_options_are_user_errors(given: dict, culprit: str) -> None:
    with pytest.raises(UserError, match=culprit.replace("+", r"\+")):
        build_config(StorageConfig, False, given)


def test_bad_flag_on_the_command_line_is_one_error_line_and_exit_2() -> None:
    argv = [sys.executable, "-m", "bench", "storage", "--users", "1,0"]
    result = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "--users = 0 is below 1" in errors[0], result.stderr
    assert "Traceback" not in result.stderr + result.stdout


def test_gi_camera_of_an_entry_keeps_its_view() -> None:
    """The growth law bakes each sampled entry at every resolution from the entry's own GI camera."""
    spec = load_scene("lung_plane")
    cam, _ = session_frames(spec, plan_sessions(spec, 1, 1, 5), DEFAULT_LIGHT_CELL, 90.0).frames[3]
    big = gi_camera(spec, cam.origin, cam.target, cam.up, cam.fov, 512)
    assert big.width == 512 and big.origin == cam.origin and big.target == cam.target and big.fov == cam.fov
