"""`cloudbaking-prebake --space all` on a two-node Ray cluster simulated on one machine:
``ray.cluster_utils.Cluster`` with two nodes of 1 CPU each bakes a small configuration space (6 maps at
16², 1 spp); each task's node is recorded, both nodes work, the driver alone writes and the tree holds
every configuration's map exactly once; the command line as its own driver, killed with -9, leaves no
task rendering on the cluster, and its rerun (from this process, the cluster's driver) completes the tree."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest

from baseline_cloudbaking.bake import configuration_space
from baseline_cloudbaking.prebake_cli import PrebakeConfig, prebake_scene
from baseline_cloudbaking.protocol import decode_payload
from baseline_cloudbaking.store import GITree
from baseline_cloudbaking.viewpoints import Tolerance
from gicore.executor import RayExecutor, simulated_ray_cluster
from gicore.scene import SceneSpec, load_scene
from tests.gicore.test_executor_ray import busy_ray_workers
from tests.helpers.cli import BIN, run_main
from tests.helpers.cloud import write_scenes
from tests.helpers.guards import HANG_GUARD_S

#: A tolerance of 1 scene unit / 30° and a 10-unit light cell: ball_moving's space is 3 views x 2 light states.
TOLERANCE = Tolerance(1.0, 30.0)
BAKE = PrebakeConfig(resolution=16, spp=1, tolerance=TOLERANCE, light_cell=10.0, space="all", seed=5)
MAPS = 6


@pytest.fixture(scope="module")
def cluster_address() -> Iterator[str]:
    """Two Ray nodes of 1 CPU each on this machine, this process their driver; both stopped at the end."""
    with simulated_ray_cluster(2) as address:
        yield address


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("cluster_scenes"))


@pytest.fixture(scope="module")
def spec(scenes: Path) -> SceneSpec:
    return load_scene(scenes / "ball_moving.json")


def alive_nodes() -> set[str]:
    import ray

    return {n["NodeID"] for n in ray.nodes() if n["Alive"]}


def stored(store: Path) -> list[tuple]:
    """(light cell, eye) of every entry, each payload complete and decodable; no stray files."""
    with GITree(store) as tree:
        assert tree.verify() == []
        entries = tree.entries()
        files = sorted(p.name for p in tree.payload_dir.rglob("*") if p.is_file())
        assert files == sorted(f"{e.sha}.gim" for e in entries)
        out = []
        for e in entries:
            header = decode_payload(tree.payload_path(e.sha).read_bytes()).header
            assert tuple(header["camera"]["origin"]) == pytest.approx(e.view.eye)
            out.append((e.key.light_cell, e.view.eye))
        return out


@pytest.mark.slow
def test_the_space_bakes_on_both_nodes_and_the_tree_holds_each_map_once(
    cluster_address: str, spec: SceneSpec, tmp_path: Path
) -> None:
    space = configuration_space(spec, TOLERANCE, BAKE.light_cell)
    assert space.size == MAPS and len(space.lights) == 2
    ran_on: dict[tuple, list[str]] = defaultdict(list)
    executor = RayExecutor(placed=lambda job, node: ran_on[tuple(job[2]), job[0]].append(node))
    started = time.monotonic()
    result = prebake_scene(tmp_path, "ball_moving", spec, BAKE, executor, progress=False)
    print(f"{MAPS} maps on two 1-CPU nodes in {time.monotonic() - started:.1f} s: {dict(executor.nodes)}")
    assert (result.frames, result.served, result.baked) == (MAPS, MAPS, MAPS)
    # Every task ran once (no retry), and both nodes of the cluster ran some.
    assert len(ran_on) == MAPS and all(len(nodes) == 1 for nodes in ran_on.values())
    nodes = {nodes[0] for nodes in ran_on.values()}
    assert nodes == alive_nodes() and len(nodes) == 2
    assert sum(executor.nodes.values()) == MAPS and set(executor.nodes) == nodes
    # The tree: one entry per configuration (light cell x grid view), none twice.
    entries = stored(tmp_path)
    expected = {(cell, tuple(map(float, eye))) for cell, _ in space.lights for eye in space.eyes}
    assert len(entries) == MAPS and set(entries) == expected
    # A rerun finds every configuration stored and bakes nothing.
    again = prebake_scene(tmp_path, "ball_moving", spec, BAKE, RayExecutor(), progress=False)
    assert (again.served, again.baked) == (MAPS, 0) and len(stored(tmp_path)) == MAPS


def prebake_argv(scenes: Path, store: Path, address: str) -> list[str]:
    """The command line of a space prebake on the cluster at ``address`` (32², 64 spp: each node's first map
    starts its worker's renderer and denoiser, seconds in which both nodes are seen rendering)."""
    return [
        str(BIN / "cloudbaking-prebake"),
        str(scenes / "ball_moving.json"),
        "--store",
        str(store),
        "--space",
        "all",
        "--tolerance-p",
        str(TOLERANCE.position),
        "--tolerance-deg",
        str(TOLERANCE.angle_deg),
        "--light-cell",
        str(BAKE.light_cell),
        "--resolution",
        "32",
        "--spp",
        "64",
        "--executor",
        "ray",
        "--ray-address",
        address,
    ]


@pytest.mark.slow
def test_kill_9_of_the_driver_stops_its_tasks_and_the_rerun_completes(
    cluster_address: str,
    scenes: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
) -> None:
    """The command line as its own driver on the cluster: killed with -9 while both nodes render, Ray fails
    the dead owner's tasks (nothing keeps rendering) and the cluster lives on; the rerun bakes the rest (the
    command's ``main`` in this process, which keeps its connection to the cluster and its warm workers)."""
    argv = prebake_argv(scenes, tmp_path, cluster_address)
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + HANG_GUARD_S
    while len(busy_ray_workers()) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(busy_ray_workers()) == 2, "both nodes should be rendering"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    killed = time.monotonic()
    while busy_ray_workers() and time.monotonic() - killed < HANG_GUARD_S:  # Ray notices the dead owner late when busy
        time.sleep(0.1)
    print(f"the dead driver's tasks ended {time.monotonic() - killed:.1f} s after kill -9")
    assert busy_ray_workers() == [] and len(alive_nodes()) == 2
    partial = len(stored(tmp_path)) if (tmp_path / "index.sqlite").exists() else 0
    assert partial < MAPS

    started = time.monotonic()
    rerun = run_main(["cloudbaking-prebake", *argv[1:]], tmp_path, monkeypatch, capfd)
    print(f"rerun: {MAPS - partial} maps in {time.monotonic() - started:.1f} s")
    assert rerun.returncode == 0, rerun.stderr
    assert f"{MAPS}/{MAPS} configurations of the space stored; {MAPS - partial} maps baked now" in rerun.stdout
    per_node = next(line for line in rerun.stdout.splitlines() if "maps per Ray node:" in line)
    counts = [int(part.split()[1]) for part in per_node.split(": ", 2)[2].split(", ")]
    assert sum(counts) == MAPS - partial and len(counts) <= 2, per_node
    entries = stored(tmp_path)
    assert len(entries) == len(set(entries)) == MAPS
