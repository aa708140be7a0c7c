"""scripts/gpu_recipe.sh, with a stand-in Python that records each command: it renders the five scenes and the
randomised ones, trains every model on all of them with one output encoding, and refuses to train without the
randomised scenes' folders."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FAKE_PYTHON = """#!/usr/bin/env bash
echo "$*" >> "$LOG"
"""


def run_recipe(tmp_path: Path, **env: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    fake = tmp_path / "python"
    fake.write_text(FAKE_PYTHON)
    fake.chmod(0o755)
    log = tmp_path / "calls.log"
    log.unlink(missing_ok=True)
    variables = {"PYTHON": str(fake), "LOG": str(log), "WORK": str(tmp_path / "work"), "RANDOM_SCENES": "3"} | env
    proc = subprocess.run(
        ["bash", str(ROOT / "scripts" / "gpu_recipe.sh")],
        env=os.environ | variables,
        capture_output=True,
        text=True,
        timeout=60,
    )
    return proc, log.read_text().splitlines() if log.is_file() else []


def test_the_recipe_renders_the_randomised_scenes_and_trains_on_them(tmp_path: Path) -> None:
    proc, calls = run_recipe(tmp_path, STAGES="render")
    assert proc.returncode == 0, proc.stderr
    random = [c for c in calls if "--random 3" in c]
    assert len(calls) == 6 and len(random) == 1 and "--seed 3" in random[0] and "--out " in random[0]
    random_root = tmp_path / "work" / "datasets" / "random"
    for i in range(3):  # what the render stage leaves
        (random_root / f"random3_{i:04d}").mkdir(parents=True)
        (random_root / f"random3_{i:04d}" / "meta.json").write_text("{}")
    proc, calls = run_recipe(tmp_path, STAGES="train")
    assert proc.returncode == 0, proc.stderr
    assert len(calls) == 3 and all(c.startswith("-m gigan_local.train_cli") for c in calls)
    for call in calls:  # the same data and encoding for GIGAN and both rivals
        assert "--demodulate" in call.split() and "lung_plane" in call
        assert all(f"random3_{i:04d}" in call for i in range(3))
    _, calls = run_recipe(tmp_path, STAGES="train", DEMODULATE="0", MODELS="gigan")
    assert "--no-demodulate" in calls[0].split()


def test_training_without_the_randomised_scenes_is_refused(tmp_path: Path) -> None:
    proc, calls = run_recipe(tmp_path, STAGES="train")
    assert proc.returncode == 2 and "run STAGES=render first" in proc.stderr and not calls
    proc, calls = run_recipe(tmp_path, STAGES="train", RANDOM_SCENES="0", MODELS="gigan")
    assert proc.returncode == 0 and "random3_" not in calls[0]
