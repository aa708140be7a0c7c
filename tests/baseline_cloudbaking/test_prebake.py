"""`cloudbaking-prebake` as a real process: bakes a fly-through, resumes, survives kill -9 and Ctrl-C."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest

from baseline_cloudbaking.bake import fly_through
from baseline_cloudbaking.protocol import decode_payload
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree, Tolerance, simulate_fill
from gicore.scene import load_scene
from tests.helpers.cloud import BIN, RES, SPP, write_scenes


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("prebake_scenes"))


def prebake_cmd(spec: Path, store: Path, frames: int, *extra: str) -> list[str]:
    size = ["--frames", str(frames), "--resolution", str(RES), "--spp", str(SPP)]
    return [str(BIN / "cloudbaking-prebake"), str(spec), "--store", str(store), *size, *extra]


def expected_entries(spec_path: Path, frames: int) -> int:
    """Maps the path needs, planned without a store (the same rule as the prebake's)."""
    path = fly_through(load_scene(spec_path), frames, RES, DEFAULT_LIGHT_CELL)
    return len(set(simulate_fill([f.view for f in path], [f.cell for f in path], Tolerance())))


def check_store(store: Path) -> int:
    """Every entry's file complete and decodable, no stray files; returns the entry count."""
    with GITree(store) as tree:
        assert tree.verify() == []
        entries = tree.entries()
        files = sorted(p.name for p in tree.payload_dir.rglob("*") if p.is_file())
        assert files == sorted(f"{e.sha}.gim" for e in entries)  # no temporaries, no orphans
        for e in entries:
            decode_payload(tree.payload_path(e.sha).read_bytes())
        return len(entries)


def count_rows(store: Path) -> int:
    try:
        with sqlite3.connect(f"file:{store / 'index.sqlite'}?mode=ro", uri=True, timeout=1) as db:
            return db.execute("SELECT COUNT(*) FROM entries").fetchone()[0]
    except sqlite3.OperationalError:  # not created yet
        return 0


def test_static_scene_bakes_without_light_level(scenes_dir: Path, tmp_path: Path) -> None:
    spec, store = scenes_dir / "ball_static.json", tmp_path / "store"
    first = subprocess.run(prebake_cmd(spec, store, 12), check=False, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    n = expected_entries(spec, 12)
    assert f"12/12 frames served by the store; {n} maps baked now" in first.stdout
    with GITree(store) as tree:
        entries = tree.entries()
        assert len(entries) == n and {e.key.light_cell for e in entries} == {None}
        assert {e.key.resolution for e in entries} == {RES} and {e.key.codec for e in entries} == {"jpeg"}
        assert "light" not in decode_payload(tree.payload_path(entries[0].sha).read_bytes()).header


def test_kill_9_mid_bake_then_reopen_and_resume(scenes_dir: Path, tmp_path: Path) -> None:
    spec, store = scenes_dir / "ball_moving.json", tmp_path / "store"
    frames = 40
    total = expected_entries(spec, frames)
    assert total > 10
    proc = subprocess.Popen(
        prebake_cmd(spec, store, frames), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.monotonic() + 90
    while count_rows(store) < 4 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL  # killed, not finished
    partial = check_store(store)
    assert 4 <= partial < total
    resumed = subprocess.run(prebake_cmd(spec, store, frames), check=False, capture_output=True, text=True, timeout=180)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{total - partial} maps to bake" in resumed.stderr
    assert check_store(store) == total


@pytest.mark.slow
def test_ctrl_c_in_a_worker_pool_leaves_a_resumable_store(scenes_dir: Path, tmp_path: Path) -> None:
    spec, store = scenes_dir / "ball_moving.json", tmp_path / "store"
    frames = 30
    proc = subprocess.Popen(
        prebake_cmd(spec, store, frames, "--workers", "2"), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 120
    while count_rows(store) < 3 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted: rerun the same command" in err and "Traceback" not in err
    partial = check_store(store)
    resumed = subprocess.run(
        prebake_cmd(spec, store, frames, "--workers", "2"), check=False, capture_output=True, text=True, timeout=240
    )
    assert resumed.returncode == 0, resumed.stderr
    assert check_store(store) == expected_entries(spec, frames) > partial
