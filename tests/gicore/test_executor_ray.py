"""The render executor on Ray: a local Ray instance (2 CPUs, started once for the module) renders a tiny data
set and a tiny prebake identical to the local pool's, retries a task whose worker died (Ray reruns it whatever
the job does, and a frame's bytes do not depend on the process that renders it: the pool comparison), cancels
its tasks when the driver is interrupted, and `gicore-dataset --executor ray` as its own driver keeps whole
frames on Ctrl-C. The command-line errors are tests/gicore/test_executor_cli.py's; `bench scaling` is
tests/bench/test_scaling.py's."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest

from baseline_cloudbaking.prebake_cli import PrebakeConfig, prebake_scene
from baseline_cloudbaking.protocol import unpack
from baseline_cloudbaking.store import GITree
from gicore.dataset_cli import DatasetConfig, build_dataset
from gicore.error_policy import UserError
from gicore.executor import (
    RAY_WORKER_NICENESS,
    InProcess,
    LocalPool,
    RayExecutor,
    Task,
    equal_priority_ray_workers,
    local_ray,
)
from gicore.fileio import TMP_MARKER
from gicore.scene import SceneSpec, load_scene
from tests.helpers.cli import BIN, run_main
from tests.helpers.cloud import write_scenes
from tests.helpers.dataset import npz_arrays
from tests.helpers.guards import HANG_GUARD_S

#: 32², 2 + 1 frames at 4 spp with OIDN: every buffer and the denoiser, cheap on 2 cores.
CFG = DatasetConfig(n_train=2, n_val=1, resolution=32, spp=4, denoise=True, seed=3)
#: Frames slow enough (~0.4 s each on one thread) to interrupt a run in the middle of one; not denoised (CFG's
#: frames test OIDN on Ray), which spares each worker the denoiser's start.
SLOW = replace(CFG, n_train=3, n_val=1, spp=1024, denoise=False)
BAKE = PrebakeConfig(frames=10, codec="jpeg", resolution=32, spp=4, seed=3)


@pytest.fixture(scope="module")
def ray_address() -> Iterator[str]:
    """A local Ray instance for the whole module (its start costs seconds); yields its head's address."""
    with local_ray(2) as address:
        yield address


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
    """PIDs of this process's Ray workers running a render job now (Ray titles a busy worker ``ray::<function>``:
    ``gicore.executor.run_ray_job``). Only descendants of this process count: the module's instance runs below
    it, and other test processes (bench scaling, the cluster test) may run Ray jobs on the machine meanwhile."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if cmdline.read_bytes().startswith(b"ray::run_ray_job"):
                pids.append(int(cmdline.parent.name))
        except OSError:  # the process ended while we looked
            continue
    return [pid for pid in pids if _descends_from(pid, os.getpid())]


def _descends_from(pid: int, ancestor: int) -> bool:
    while pid > 1:
        try:
            # the parent is the 4th field of /proc/PID/stat, after the command in parentheses
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):  # the process ended while we looked
            return False
        if pid == ancestor:
            return True
    return False


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


@pytest.mark.slow
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


# --- the command line as its own driver ------------------------------------------------------------
# (before the tests below kill or cancel workers: the in-process rerun finds this module's workers warm)


@pytest.mark.slow
def test_ctrl_c_of_a_ray_run_keeps_whole_frames_and_the_rerun_finishes_identical(
    ray_address: str,
    scenes: Path,
    slow_reference: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
) -> None:
    """gicore-dataset --executor ray --ray-address HOST:PORT as its own driver process joining the module's
    instance; the rerun joins it from this process (whose connection a command keeps)."""
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
        "--no-denoise",
    ]
    root = tmp_path / "ball_moving"
    # Ray 2.60's core worker sometimes aborts a driver interrupted while a task reply is in flight
    # ("Check failed: ... Tried to complete task that was not pending", about 1 run in 5 here): an
    # upstream bug, not ours. Such a run is tried again from scratch; any other outcome is judged.
    for _attempt in range(3):
        shutil.rmtree(root, ignore_errors=True)
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + HANG_GUARD_S  # interrupt once the first frame is kept
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
    rerun = run_main(["gicore-dataset", *argv[1:]], tmp_path, monkeypatch, capfd)
    assert rerun.returncode == 0, rerun.stderr
    assert "ball_moving: 4 frames in" in rerun.stdout
    assert_same_dataset(slow_reference, root)


# --- the executor itself -----------------------------------------------------------------------------


def _niceness() -> int:
    return os.nice(0)


def test_ray_workers_run_at_the_drivers_priority(ray_address: str) -> None:
    """Ray's default niceness (15) would leave its workers starved beside any busy process."""
    import ray

    assert ray.get(ray.remote(_niceness).remote()) == _niceness()


def test_a_niceness_the_user_chose_for_ray_workers_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(RAY_WORKER_NICENESS, "10")
    equal_priority_ray_workers()
    assert os.environ[RAY_WORKER_NICENESS] == "10"
    monkeypatch.delenv(RAY_WORKER_NICENESS)
    equal_priority_ray_workers()
    assert os.environ[RAY_WORKER_NICENESS] == "0"


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
        RayExecutor().run(Task(_marker, (str(tmp_path),), _sleep), [0.0, *[HANG_GUARD_S] * 3], interrupt)
    # the long sleeps were stopped: their workers are idle long before the sleeps could have ended
    deadline = interrupted[0] + HANG_GUARD_S / 4
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
