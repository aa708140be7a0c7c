"""The render executor on Ray: a local Ray instance (2 CPUs, started once for the module)
renders a tiny data set and a tiny prebake identical to the local pool's, survives a worker killed
mid-frame, cancels its tasks on Ctrl-C, and the command lines fail in one line where they should;
`bench scaling` measures both executors and labels its projections."""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from baseline_cloudbaking.bake import configuration_space
from baseline_cloudbaking.prebake_cli import PrebakeConfig, prebake_scene
from baseline_cloudbaking.protocol import unpack
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree
from baseline_cloudbaking.viewpoints import Tolerance
from gicore.dataset_cli import DatasetConfig, build_dataset
from gicore.error_policy import UserError
from gicore.executor import InProcess, LocalPool, RayExecutor, Task
from gicore.fileio import TMP_MARKER
from gicore.results import read_rows
from gicore.scene import SceneSpec, builtin_scenes, load_scene
from tests.helpers.cloud import BIN, write_scenes
from tests.helpers.dataset import npz_arrays

#: 32², 2 + 1 frames at 4 spp with OIDN: every buffer and the denoiser, cheap on 2 cores.
CFG = DatasetConfig(n_train=2, n_val=1, resolution=32, spp=4, denoise=True, seed=3)
#: Frames slow enough (~0.4 s each on one thread) to kill or interrupt a worker in the middle of one.
SLOW = replace(CFG, n_train=3, n_val=1, spp=1024)
BAKE = PrebakeConfig(frames=10, codec="jpeg", resolution=32, spp=4, seed=3)
#: Hang guard of every process and wait here, never a bound the tests judge (a busy 2-core machine is slow).
TIMEOUT_S = 600


@pytest.fixture(scope="module")
def ray_address() -> Iterator[str]:
    """A local Ray instance for the whole module (its start costs seconds); yields its head's address."""
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("ray_scenes"))


@pytest.fixture(scope="module")
def spec(scenes: Path) -> SceneSpec:
    return load_scene(scenes / "ball_moving.json")


@pytest.fixture(scope="module")
def local_pool() -> Iterator[LocalPool]:
    with LocalPool(2) as pool:
        yield pool


@pytest.fixture(scope="module")
def pool_dataset(spec: SceneSpec, local_pool: LocalPool, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("pool") / spec.name
    build_dataset(spec, root, CFG, local_pool, progress=False)
    return root


@pytest.fixture(scope="module")
def slow_reference(spec: SceneSpec, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("slow") / spec.name
    build_dataset(spec, root, SLOW, InProcess(), progress=False)
    return root


def assert_same_dataset(a: Path, b: Path) -> None:
    """Same meta.json, same frame files, byte-identical arrays of the same dtype; no temporaries."""
    assert (a / "meta.json").read_bytes() == (b / "meta.json").read_bytes()
    fa, fb = npz_arrays(a), npz_arrays(b)
    assert sorted(fa) == sorted(fb) and len(fa) == len(list(a.rglob("*.npz")))
    for name, arrays in fa.items():
        assert sorted(arrays) == sorted(fb[name]), name
        for key, arr in arrays.items():
            assert arr.dtype == fb[name][key].dtype and arr.tobytes() == fb[name][key].tobytes(), f"{name}:{key}"
    assert not [p for p in b.rglob(f"*{TMP_MARKER}*")]


def store_entries(store: Path) -> dict:
    """(key, viewpoint) -> (payload header without the bake's own timings, section bytes) of a GI tree."""
    with GITree(store) as tree:
        assert tree.verify() == []
        out = {}
        for entry in tree.entries():
            header, sections = unpack(tree.payload_path(entry.sha).read_bytes())
            assert set(header.pop("bake_ms")) == {"render", "denoise", "encode"}  # wall times: differ run to run
            out[entry.key, entry.view] = (header, {name: bytes(data) for name, data in sections.items()})
        return out


def busy_ray_workers() -> list[int]:
    """PIDs of Ray workers running a render job now (Ray titles a busy worker ``ray::<function>``:
    ``gicore.executor.run_ray_job``)."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if cmdline.read_bytes().startswith(b"ray::run_ray_job"):
                pids.append(int(cmdline.parent.name))
        except OSError:  # the process ended while we looked
            continue
    return pids


# --- worker functions of the generic tests (module level: Ray workers import them by name) -----------


def _marker(path: str) -> Path:
    return Path(path)


def _exit_once(marker: Path, job: int) -> int:
    """Job 2 kills its worker process the first time it runs (no result, no clean-up), as a crash would."""
    if job == 2 and not marker.exists():
        marker.touch()
        os._exit(1)
    return job * 10


def _sleep(_: Path, seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def _refuse(_: Path, job: int) -> int:
    raise UserError(f"job {job} names a missing file", "give an existing one")


# --- data set and prebake: Ray against the local pool ------------------------------------------------


def test_dataset_on_ray_equals_the_local_pool_and_resumes(
    ray_address: str, spec: SceneSpec, pool_dataset: Path, tmp_path: Path
) -> None:
    root = tmp_path / spec.name
    meta = build_dataset(spec, root, CFG, RayExecutor(), progress=False)
    assert len(meta.frames) == 3 and meta.frames[0].light is not None  # a moving light: recorded per frame
    assert_same_dataset(pool_dataset, root)
    # A resumed run renders only what is missing: the kept files are not rewritten.
    lost = root / "train" / "000001.npz"
    lost.unlink()
    kept = {p: p.stat().st_mtime_ns for p in root.rglob("*.npz")}
    build_dataset(spec, root, CFG, RayExecutor(workers=1), progress=False)
    assert {p: p.stat().st_mtime_ns for p in kept} == kept and lost.is_file()
    assert_same_dataset(pool_dataset, root)


def test_prebake_on_ray_equals_the_local_pool_and_resumes(
    ray_address: str, spec: SceneSpec, local_pool: LocalPool, tmp_path: Path
) -> None:
    pooled = prebake_scene(tmp_path / "pool", "ball_moving", spec, BAKE, local_pool, progress=False)
    on_ray = prebake_scene(tmp_path / "ray", "ball_moving", spec, BAKE, RayExecutor(), progress=False)
    # Stored bytes differ by a few: each header records its bake's own wall times.
    assert (
        (on_ray.served, on_ray.baked) == (pooled.served, pooled.baked)
        and pooled.served == BAKE.frames
        and pooled.baked >= 3
    )
    entries = store_entries(tmp_path / "ray")
    assert len(entries) == pooled.baked and entries == store_entries(tmp_path / "pool")
    again = prebake_scene(tmp_path / "ray", "ball_moving", spec, BAKE, RayExecutor(), progress=False)
    assert (again.baked, again.served) == (0, BAKE.frames)


def test_a_worker_killed_mid_frame_is_retried_and_the_output_is_identical(
    ray_address: str, spec: SceneSpec, slow_reference: Path, tmp_path: Path
) -> None:
    killed: list[int] = []
    done = threading.Event()

    def kill_one_busy_worker() -> None:
        while not done.is_set() and not killed:
            for pid in busy_ray_workers():
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                break
            time.sleep(0.002)

    killer = threading.Thread(target=kill_one_busy_worker)
    killer.start()
    try:
        build_dataset(spec, tmp_path / spec.name, SLOW, RayExecutor(), progress=False)
    finally:
        done.set()
        killer.join()
    assert len(killed) == 1, "no worker was caught in the middle of a frame"
    assert_same_dataset(slow_reference, tmp_path / spec.name)


# --- the executor itself -----------------------------------------------------------------------------


def test_a_task_whose_worker_dies_is_retried(ray_address: str, tmp_path: Path) -> None:
    marker = tmp_path / "exited"
    got: dict[int, int] = {}
    RayExecutor(max_retries=2).run(Task(_marker, (str(marker),), _exit_once), [0, 1, 2, 3], got.__setitem__)
    assert marker.exists() and got == {0: 0, 1: 10, 2: 20, 3: 30}


def test_without_retries_a_dead_worker_fails_the_run(ray_address: str, tmp_path: Path) -> None:
    import ray

    marker = tmp_path / "exited"
    with pytest.raises(ray.exceptions.WorkerCrashedError):
        RayExecutor(max_retries=0).run(Task(_marker, (str(marker),), _exit_once), [2], lambda job, result: None)
    assert marker.exists()


def test_interrupting_the_driver_cancels_the_running_tasks(ray_address: str, tmp_path: Path) -> None:
    interrupted: list[float] = []

    def interrupt(job: float, result: float) -> None:
        interrupted.append(time.monotonic())
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        RayExecutor().run(Task(_marker, (str(tmp_path),), _sleep), [0.0, 60.0, 60.0, 60.0], interrupt)
    # the 60 s sleeps were stopped: their workers are idle long before the sleeps could have ended
    deadline = interrupted[0] + 40
    while busy_ray_workers() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert busy_ray_workers() == []


@pytest.mark.parametrize("backend", ["local_pool", "ray"])
def test_a_user_error_in_a_job_reaches_the_driver_whole(
    backend: str, request: pytest.FixtureRequest, tmp_path: Path
) -> None:
    if backend == "ray":
        request.getfixturevalue("ray_address")
        executor = RayExecutor()
    else:
        executor = request.getfixturevalue("local_pool")
    with pytest.raises(UserError) as caught:
        executor.run(Task(_marker, (str(tmp_path),), _refuse), [7], lambda job, result: None)
    assert type(caught.value) is UserError and str(caught.value) == "job 7 names a missing file: give an existing one"


# --- command lines -----------------------------------------------------------------------------------


#: Runs a console script's main with Ray made unimportable, as on an install without the extra.
WITHOUT_RAY = "import sys; sys.modules['ray'] = None; from {} import main; main()"
MODULES = {
    "gicore-dataset": "gicore.dataset_cli",
    "cloudbaking-prebake": "baseline_cloudbaking.prebake_cli",
    "bench": "bench.cli",
}


def run_cli(argv: list[str], cwd: Path, *, without_ray: bool = False) -> subprocess.CompletedProcess:
    """Console script ``argv[0]`` with the arguments ``argv[1:]``."""
    script = [sys.executable, "-c", WITHOUT_RAY.format(MODULES[argv[0]])] if without_ray else [str(BIN / argv[0])]
    return subprocess.run([*script, *argv[1:]], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S)


def one_error_line(proc: subprocess.CompletedProcess, culprit: str) -> None:
    assert proc.returncode == 2, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and culprit in errors[0], proc.stderr
    assert "Traceback" not in proc.stderr


DATASET = [
    "gicore-dataset",
    "ball_moving.json",
    "--out",
    "out",
    "--train",
    "1",
    "--val",
    "0",
    "--resolution",
    "8",
    "--spp",
    "1",
    "--no-denoise",
]
PREBAKE = [
    "cloudbaking-prebake",
    "ball_moving.json",
    "--store",
    "store",
    "--frames",
    "2",
    "--resolution",
    "16",
    "--spp",
    "1",
]


@pytest.mark.parametrize("argv", [DATASET, PREBAKE], ids=["dataset", "prebake"])
@pytest.mark.parametrize(
    ("address", "culprit"),
    [
        ("127.0.0.1:1", "{} 127.0.0.1:1: no Ray cluster answers there (Connection refused)"),
        ("headnode", "{} 'headnode' is neither 'auto' nor HOST:PORT"),
        ("10.0.0.5:99999", "{} '10.0.0.5:99999' is neither 'auto' nor HOST:PORT"),
    ],
)
def test_a_bad_ray_address_is_one_error_line(argv: list[str], address: str, culprit: str, scenes: Path) -> None:
    # the culprit is the address check's, made before Ray is asked (which would reconnect for minutes)
    one_error_line(
        run_cli([*argv, "--executor", "ray", "--ray-address", address], scenes), culprit.format("--ray-address")
    )
    assert not (scenes / "out").exists() and not (scenes / "store" / "index.sqlite").exists()


@pytest.mark.parametrize("argv", [DATASET, PREBAKE], ids=["dataset", "prebake"])
def test_a_ray_address_without_executor_ray_is_one_error_line(argv: list[str], scenes: Path) -> None:
    one_error_line(
        run_cli([*argv, "--ray-address", "auto"], scenes),
        "--ray-address needs --executor ray: add --executor ray, or leave out --ray-address",
    )
    assert not (scenes / "out").exists() and not (scenes / "store" / "index.sqlite").exists()


NOT_INSTALLED = "needs Ray, which is not installed: install it with pip install '.[ray]'"


@pytest.mark.parametrize(
    ("argv", "culprit"),
    [
        ([*DATASET, "--executor", "ray"], f"--executor ray {NOT_INSTALLED}"),
        ([*PREBAKE, "--executor", "ray"], f"--executor ray {NOT_INSTALLED}"),
        (["bench", "scaling", "--quick", "--out", "out"], f"--executors ray {NOT_INSTALLED}"),
    ],
    ids=["dataset", "prebake", "bench-scaling"],
)
def test_ray_not_installed_names_the_extra(argv: list[str], culprit: str, scenes: Path) -> None:
    one_error_line(run_cli(argv, scenes, without_ray=True), culprit)
    assert not (scenes / "out").exists()


def test_without_ray_the_local_paths_import_and_render(scenes: Path, tmp_path: Path) -> None:
    imports = (
        "import sys; import gicore, gicore.executor, gicore.dataset_cli, baseline_cloudbaking.prebake_cli, bench.cli; "
        "assert 'ray' not in sys.modules"
    )
    assert (
        subprocess.run([sys.executable, "-c", imports], capture_output=True, text=True, timeout=TIMEOUT_S).returncode
        == 0
    )
    out = tmp_path / "out"
    proc = run_cli([*DATASET[:3], str(out), *DATASET[4:]], scenes, without_ray=True)
    assert proc.returncode == 0, proc.stderr
    assert [p.name for p in out.rglob("*.npz")] == ["000000.npz"]


@pytest.mark.slow
def test_ctrl_c_of_a_ray_run_keeps_whole_frames_and_the_rerun_finishes_identical(
    ray_address: str, scenes: Path, slow_reference: Path, tmp_path: Path
) -> None:
    """gicore-dataset --executor ray --ray-address HOST:PORT as its own driver process joining the module's
    instance."""
    argv = [str(BIN / "gicore-dataset"), str(scenes / "ball_moving.json"), "--out", str(tmp_path)]
    argv += ["--executor", "ray", "--ray-address", ray_address]
    argv += [
        "--train",
        str(SLOW.n_train),
        "--val",
        str(SLOW.n_val),
        "--resolution",
        str(SLOW.resolution),
        "--spp",
        str(SLOW.spp),
        "--seed",
        str(SLOW.seed),
    ]
    root = tmp_path / "ball_moving"
    # Ray 2.60's core worker sometimes aborts a driver interrupted while a task reply is in flight
    # ("Check failed: ... Tried to complete task that was not pending", about 1 run in 5 here): an
    # upstream bug, not ours. Such a run is tried again from scratch; any other outcome is judged.
    for _attempt in range(3):
        shutil.rmtree(root, ignore_errors=True)
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + TIMEOUT_S  # interrupt once the first frame is kept
        while not list(root.rglob("*.npz")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert list(root.rglob("*.npz")), "no frame was kept before the hang guard: " + str(proc.poll())
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        if "Tried to complete task that was not pending" not in err:
            break
    assert proc.returncode == 130, err
    assert "interrupted: finished frames are kept" in err and "Traceback" not in err
    partial = npz_arrays(root)
    assert 1 <= len(partial) < SLOW.n_train + SLOW.n_val and not list(root.rglob(f"*{TMP_MARKER}*"))
    reference = npz_arrays(slow_reference)
    for name, arrays in partial.items():
        assert all(arrays[k].tobytes() == reference[name][k].tobytes() for k in arrays), name
    rerun = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert rerun.returncode == 0, rerun.stderr
    assert "ball_moving: 4 frames in" in rerun.stdout
    assert_same_dataset(slow_reference, root)


# --- bench scaling ------------------------------------------------------------------------------------


@pytest.mark.slow
def test_bench_scaling_measures_every_executor_and_labels_the_projection(tmp_path: Path) -> None:
    """A tiny `bench scaling` (its own Ray instance and simulated clusters, as a user runs it): every measured
    point (local, Ray, 1 and 2 Ray nodes), the per-task overhead, and projections that follow from the measured
    1-worker item time and say they are projections."""
    tiny = [
        "--resolution",
        "16",
        "--spp",
        "1",
        "--frames",
        "2",
        "--maps",
        "2",
        "--overhead-jobs",
        "3",
        "--project-workers",
        "1,4",
    ]
    proc = subprocess.run(
        [str(BIN / "bench"), "scaling", "--quick", *tiny, "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=480,
    )
    assert proc.returncode == 0, proc.stderr
    rows = read_rows(tmp_path / "scaling.csv")

    def only(**match: object) -> dict:
        found = [r for r in rows if all((r[k] if k in r else r["config"].get(k)) == v for k, v in match.items())]
        assert len(found) == 1, match
        return found[0]

    for ex in ("local", "ray", "ray-cluster"):
        assert 0 < only(system=ex, metric="task_roundtrip", stat="median", workers=1)["value"] < 1000  # ms
        for kind, unit in (("frame", "frames/s"), ("map", "maps/s")):
            for workers in (1, 2):
                row = only(system=ex, metric="throughput", workers=workers, kind=kind)
                assert row["stat"] == "value" and row["unit"] == unit and row["value"] > 0
            assert only(system=ex, metric="efficiency", workers=2, kind=kind)["value"] > 0
    assert only(system="ray", metric="instance_start")["value"] > 0
    for nodes in (1, 2):  # a cluster per point, as many 1-CPU nodes as workers
        assert only(system="ray-cluster", metric="instance_start", nodes=nodes)["value"] > 0
        for kind in ("frame", "map"):
            assert 1 <= only(system="ray-cluster", metric="nodes_used", workers=nodes, kind=kind)["value"] <= nodes
    assert "Two simulated Ray nodes (1 CPU each, sharing this machine's cores)" in (tmp_path / "scaling.md").read_text()
    maps = {r["scene"]: r["value"] for r in rows if r["metric"] == "bake_maps"}
    assert sorted(maps) == builtin_scenes() and all(0 < n <= 1500 for n in maps.values())
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
        per_item = measured * (r["config"]["resolution"] / 16) ** 2
        if r["scene"] != "paper_5_scenes" or kind == "frame":  # per scene; the data set's one total
            assert r["value"] == pytest.approx(
                math.ceil(r["config"]["items"] / r["config"]["workers"]) * per_item / 3600
            )
    data = only(system="ray", metric="dataset_wall", workers=1)
    assert data["config"]["items"] == 5 * 1600 and data["config"]["resolution"] == 512
    assert data["value"] == pytest.approx(4 * only(system="ray", metric="dataset_wall", workers=4)["value"])
    bake_total = only(system="local", scene="paper_5_scenes", metric="bake_wall", workers=4)["value"]
    assert bake_total == pytest.approx(
        sum(only(system="local", scene=s, metric="bake_wall", workers=4)["value"] for s in maps)
    )
    space_total = only(system="ray", scene="paper_5_scenes", metric="space_wall", workers=4)
    assert space_total["config"]["items"] == sum(space.values()) and space_total["value"] == pytest.approx(
        sum(only(system="ray", scene=s, metric="space_wall", workers=4)["value"] for s in space)
    )
    assert "PROJECTED, not measured" in (tmp_path / "scaling.md").read_text()
    assert (tmp_path / "scaling.png").stat().st_size > 10_000
