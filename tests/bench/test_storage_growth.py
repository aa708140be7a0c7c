"""`bench storage`'s growth law: the GI tree under many sessions, filled by the store's own lookup rule."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from baseline_cloudbaking.bake import fly_through, gi_camera
from baseline_cloudbaking.growth import session_frames
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL
from bench.runner import build_config
from bench.storage_config import RAW_CODEC, StorageConfig
from bench.storage_growth import _growth_entry_bytes, paper_accounting
from gicore.error_policy import UserError
from gicore.results import Results, read_rows
from gicore.scene import load_scene
from gicore.sessions import plan_sessions

REPO = Path(__file__).resolve().parents[2]


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
