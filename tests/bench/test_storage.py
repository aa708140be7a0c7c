"""`bench storage` against a real prebake: same entries, same bytes when every entry is rendered."""

from __future__ import annotations

from pathlib import Path

import pytest

from baseline_cloudbaking.prebake_cli import PrebakeConfig, prebake_scene
from baseline_cloudbaking.store import GITree
from baseline_cloudbaking.viewpoints import Tolerance
from bench.runner import execute
from bench.storage import BENCH, StorageConfig
from gicore.results import read_rows
from gicore.scene import load_scene
from tests.helpers.cloud import write_scenes


def test_storage_bench_matches_a_real_prebake(tmp_path: Path) -> None:
    spec_path = write_scenes(tmp_path / "scenes") / "ball_moving.json"
    tol = Tolerance(0.05, 2.0)
    cfg = StorageConfig(
        scenes=(str(spec_path),), frames=24, resolutions=(32,), codecs=("jpeg", "png"), spp=2, samples=24,
        tolerance_position=tol.position, tolerance_angle_deg=tol.angle_deg, knob_positions=(0.05, 0.5),
        knob_angles_deg=(2.0, 30.0), warp_samples=1, sessions=3, users=(2,), session_frames=24, growth_samples=1,
        capacity_samples=200, paper_resolution=32, map_cache=tmp_path / "maps",
    )  # fmt: skip
    files = execute(BENCH, cfg, tmp_path / "out")
    assert {p.name for p in files} >= {
        "storage.csv",
        "storage.provenance.json",
        "storage.md",
        "storage.png",
        "storage.svg",
        "storage_tolerance.png",
        "storage_growth.png",
    }
    rows = read_rows(tmp_path / "out" / "storage.csv")

    def value(metric: str, stat: str = "value", **config) -> float:
        return next(
            r["value"]
            for r in rows
            if r["metric"] == metric and r["stat"] == stat and config.items() <= r["config"].items()
        )

    store = tmp_path / "store"
    for codec in ("jpeg", "png"):
        prebake_scene(
            store, "ball_moving", load_scene(spec_path), PrebakeConfig(24, codec, 32, 2, tolerance=tol), progress=False
        )
    with GITree(store) as tree:
        stats = {u["codec"]: u for u in tree.stats()["by_scene_codec"]}
    entries = value("entries")
    assert stats["jpeg"]["entries"] == stats["png"]["entries"] == entries  # counted = what a prebake stores
    for codec in ("jpeg", "png"):
        row = next(
            r
            for r in rows
            if r["metric"] == "gi_tree_bytes" and r["stat"] == "estimate" and r["config"]["codec"] == codec
        )
        assert row["config"]["composition"] == "blend" and row["config"]["basis"].startswith(
            "measured"
        )  # every entry rendered
        # the same maps, encoded alike: only the timing digits in the headers differ
        assert row["value"] == pytest.approx(stats[codec]["bytes"], rel=0.002)
    assert value("entry_bytes", "mean", codec="png", composition="residual") > value(
        "entry_bytes", "mean", codec="png", composition="blend"
    )
    assert value("client_bytes", precision="fp16") < value("client_bytes", precision="fp32")
    # a looser tolerance stores fewer maps and serves more of the perturbed pass
    assert value("knob_entries", knob_position=0.5) < value("knob_entries", knob_position=0.05)
    assert value("knob_hit_rate", knob_position=0.5) >= value("knob_hit_rate", knob_position=0.05)
    assert 0.0 < value("knob_ssim_warped", "mean", knob_position=0.5) <= 1.0
    assert "| ball_moving |" in (tmp_path / "out" / "storage.md").read_text()
