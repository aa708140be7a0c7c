"""`bench scaling` as a user runs it (local processes and its own simulated Ray cluster): every measured point, the
per-task overhead, and projections that follow from the measured 1-worker item time and say they are
projections. The executors themselves are tests/gicore/test_executor_ray.py's; the bench's ``ray`` executor is its
``ray-cluster`` one on ``gicore.executor.local_ray`` (which that module runs) instead of the simulated cluster, so its
own start, the costliest part of the run, is left out here."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import pytest

from baseline_cloudbaking.bake import configuration_space
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL
from baseline_cloudbaking.viewpoints import Tolerance
from gicore.results import read_rows
from gicore.scene import builtin_scenes, load_scene
from tests.helpers.cli import BIN
from tests.helpers.guards import HANG_GUARD_S

#: Measured at 16² (the projections scale by pixel count from it).
RESOLUTION = 16
#: Fly-through frames of the projected bakes: few, as their map count is only planned (nothing rendered).
BAKE_FRAMES = 100
#: Every point's cost is its start (Ray instance, worker processes, Mitsuba): one timed frame and map per point
#: and the fewest overhead jobs with a median still show each metric.
TINY = ["--resolution", str(RESOLUTION), "--spp", "1", "--frames", "1", "--maps", "1", "--overhead-jobs", "3"]
TINY += ["--bake-frames", str(BAKE_FRAMES), "--project-workers", "1,4", "--executors", "local,ray-cluster"]


@pytest.mark.slow
def test_bench_scaling_measures_every_executor_and_labels_the_projection(tmp_path: Path) -> None:
    proc = subprocess.run(
        [str(BIN / "bench"), "scaling", "--quick", *TINY, "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert proc.returncode == 0, proc.stderr
    rows = read_rows(tmp_path / "scaling.csv")

    def only(**match: object) -> dict:
        found = [r for r in rows if all((r[k] if k in r else r["config"].get(k)) == v for k, v in match.items())]
        assert len(found) == 1, match
        return found[0]

    for ex in ("local", "ray-cluster"):
        roundtrip = only(system=ex, metric="task_roundtrip", stat="median", workers=1)
        assert roundtrip["unit"] == "ms" and roundtrip["value"] > 0
        for kind, unit in (("frame", "frames/s"), ("map", "maps/s")):
            for workers in (1, 2):
                row = only(system=ex, metric="throughput", workers=workers, kind=kind)
                assert row["stat"] == "value" and row["unit"] == unit and row["value"] > 0
            assert only(system=ex, metric="efficiency", workers=2, kind=kind)["value"] > 0
    # one cluster for every point, as many 1-CPU nodes as the most workers; a point's tasks run on up to all of them
    assert only(system="ray-cluster", metric="instance_start")["config"]["nodes"] == 2
    for workers in (1, 2):
        for kind in ("frame", "map"):
            assert 1 <= only(system="ray-cluster", metric="nodes_used", workers=workers, kind=kind)["value"] <= 2
    md = (tmp_path / "scaling.md").read_text()
    assert "A simulated Ray cluster of 2 nodes (1 CPU each, sharing this machine's cores)" in md
    assert md.count("ray, 2 nodes x 1 CPU (simulated)") == 2  # the cluster's row per worker count
    maps = {r["scene"]: r["value"] for r in rows if r["metric"] == "bake_maps"}
    assert sorted(maps) == builtin_scenes() and all(0 < n <= BAKE_FRAMES for n in maps.values())
    space = {r["scene"]: r["value"] for r in rows if r["metric"] == "space_maps"}
    assert sorted(space) == builtin_scenes()
    for scene, n in space.items():  # the whole space holds many more maps than one fly-through needs
        assert n == configuration_space(load_scene(scene), Tolerance(), DEFAULT_LIGHT_CELL).size > 10 * maps[scene]

    projected = [r for r in rows if r["metric"] in ("dataset_wall", "bake_wall", "space_wall")]
    assert projected and all(
        r["stat"] == "projection" and "linear scaling" in r["config"]["assumption"] for r in projected
    )
    for r in projected:
        kind = "frame" if r["metric"] == "dataset_wall" else "map"
        measured = only(system=r["system"], metric="item_time", workers=1, kind=kind)["value"]
        assert r["config"]["measured_item_s"] == pytest.approx(measured)
        per_item = measured * (r["config"]["resolution"] / RESOLUTION) ** 2
        if r["scene"] != "paper_5_scenes" or kind == "frame":  # per scene; the data set's one total
            assert r["value"] == pytest.approx(
                math.ceil(r["config"]["items"] / r["config"]["workers"]) * per_item / 3600
            )
    data = only(system="ray-cluster", metric="dataset_wall", workers=1)
    assert data["config"]["items"] == 5 * 1600 and data["config"]["resolution"] == 512
    assert data["value"] == pytest.approx(4 * only(system="ray-cluster", metric="dataset_wall", workers=4)["value"])
    bake_total = only(system="local", scene="paper_5_scenes", metric="bake_wall", workers=4)["value"]
    assert bake_total == pytest.approx(
        sum(only(system="local", scene=s, metric="bake_wall", workers=4)["value"] for s in maps)
    )
    space_total = only(system="ray-cluster", scene="paper_5_scenes", metric="space_wall", workers=4)
    assert space_total["config"]["items"] == sum(space.values()) and space_total["value"] == pytest.approx(
        sum(only(system="ray-cluster", scene=s, metric="space_wall", workers=4)["value"] for s in space)
    )
    assert "PROJECTED, not measured" in (tmp_path / "scaling.md").read_text()
    assert (tmp_path / "scaling.png").stat().st_size > 10_000
