"""`cloudbaking-prebake`: bakes a fly-through, resumes after kill -9 of a real process; its worker processes
end with it (kill -9, Ctrl-C, SIGTERM), an interrupt keeps the maps stored and releases its lock, a lock left by
kill -9 is taken over, and a read-only store is refused before any map is baked. What is not about a process
(a bake, a rerun, a refusal) runs the command's ``main`` in this process."""

from __future__ import annotations

import os
import shutil
import signal
import sqlite3
import subprocess
import tempfile
import time
from contextlib import suppress
from pathlib import Path

import pytest

from baseline_cloudbaking.prebake_cli import PrebakeConfig, maps_to_bake
from baseline_cloudbaking.protocol import decode_payload
from baseline_cloudbaking.store import GITree
from gicore.scene import load_scene
from tests.baseline_cloudbaking.test_store import read_only
from tests.helpers.cli import Outcome, run_main
from tests.helpers.cloud import BIN, RES, SPP, write_scenes
from tests.helpers.guards import HANG_GUARD_S


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("prebake_scenes"))


def prebake_cmd(spec: Path, store: Path, frames: int, *extra: str) -> list[str]:
    size = ["--frames", str(frames), "--resolution", str(RES), "--spp", str(SPP)]
    return [str(BIN / "cloudbaking-prebake"), str(spec), "--store", str(store), *size, *extra]


def prebake_here(
    spec: Path, store: Path, frames: int, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> Outcome:
    """:func:`prebake_cmd`'s command run by its ``main`` in this process (no interpreter start)."""
    return run_main(["cloudbaking-prebake", *prebake_cmd(spec, store, frames)[1:]], store.parent, monkeypatch, capfd)


def expected_entries(spec_path: Path, frames: int) -> int:
    """Maps the path needs, counted without a store (:func:`maps_to_bake`, which these tests hold to the prebake)."""
    return maps_to_bake(load_scene(spec_path), PrebakeConfig(frames=frames, resolution=RES))


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


def test_static_scene_bakes_without_light_level(
    scenes_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    spec, store = scenes_dir / "ball_static.json", tmp_path / "store"
    first = prebake_here(spec, store, 12, monkeypatch, capfd)
    assert first.returncode == 0, first.stderr
    n = expected_entries(spec, 12)
    assert f"12/12 frames served by the store; {n} maps baked now" in first.stdout
    with GITree(store) as tree:
        entries = tree.entries()
        assert len(entries) == n and {e.key.light_cell for e in entries} == {None}
        assert {e.key.resolution for e in entries} == {RES} and {e.key.codec for e in entries} == {"jpeg"}
        assert "light" not in decode_payload(tree.payload_path(entries[0].sha).read_bytes()).header


def test_kill_9_mid_bake_then_reopen_and_resume(
    scenes_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    spec, store = scenes_dir / "ball_moving.json", tmp_path / "store"
    frames = 16
    total = expected_entries(spec, frames)
    assert total > 10
    proc = subprocess.Popen(
        prebake_cmd(spec, store, frames), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.monotonic() + 90
    while count_rows(store) < 4 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=120)
    assert proc.returncode == -signal.SIGKILL  # killed, not finished
    partial = check_store(store)
    assert 4 <= partial < total
    resumed = prebake_here(spec, store, frames, monkeypatch, capfd)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{total - partial} maps to bake" in resumed.stderr
    assert check_store(store) == total


# --- process lifetime: workers end with the prebake, locks, a read-only store -----------------------------

#: A worker process or a lock this long past the prebake's end is a leak (left alone, one would never end; a busy
#: machine only takes longer to reap them).
GONE_S = HANG_GUARD_S
needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")


def session_processes(sid: int) -> list[int]:
    """Running processes (zombies excluded) of session ``sid``: a prebake started with
    ``start_new_session`` and every process it started (pool workers, multiprocessing's resource tracker)."""
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            state, _, _, session = stat.read_text().rsplit(")", 1)[1].split()[:4]
        except (OSError, ValueError):  # ended while we looked
            continue
        if int(session) == sid and state not in ("Z", "X"):
            pids.append(int(stat.parent.name))
    return pids


def busy_workers(sid: int) -> list[int]:
    """Pool workers of session ``sid`` that have loaded Mitsuba, i.e. build the scene or render a map."""
    busy = []
    for pid in session_processes(sid):
        with suppress(OSError):
            if (
                b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes()
                and b"mitsuba" in Path(f"/proc/{pid}/maps").read_bytes()
            ):
                busy.append(pid)
    return busy


#: Frames of a pool prebake stopped while it runs: far more maps than are baked before it is stopped.
POOL_FRAMES = 40


def start_pool_prebake(spec: Path, store: Path, log: Path) -> subprocess.Popen:
    """A prebake with two workers (in its own session), returned once both are at work."""
    with log.open("w") as err:
        proc = subprocess.Popen(
            prebake_cmd(spec, store, POOL_FRAMES, "--workers", "2"),
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,
        )
    deadline = time.monotonic() + 60
    while len(busy_workers(proc.pid)) < 2:
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.02)
    return proc


def wait_session_gone(sid: int) -> float:
    """Seconds until no process of session ``sid`` runs; kills the rest and fails past GONE_S."""
    start = time.monotonic()
    while left := session_processes(sid):
        if time.monotonic() - start > GONE_S:
            for pid in left:
                with suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            pytest.fail(f"processes of the prebake still running {GONE_S} s after it ended: {left}")
        time.sleep(0.005)
    return time.monotonic() - start


@needs_proc
def test_kill_9_of_a_pool_prebake_leaves_no_process_and_the_rerun_takes_its_lock_over(
    scenes_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    spec, store = scenes_dir / "ball_moving.json", tmp_path / "store"
    proc = start_pool_prebake(spec, store, tmp_path / "stderr.txt")
    try:
        started = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=120)
        wait_session_gone(proc.pid)
        took = time.monotonic() - started
    finally:
        with suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    print(f"prebake's workers gone {took * 1e3:.0f} ms after kill -9")
    lock = store / ".prebake" / "ball_moving" / ".lock"
    assert lock.read_text() == f"{proc.pid}\n"  # kill -9 leaves the lock file, naming the dead holder
    rerun = prebake_here(spec, store, 2, monkeypatch, capfd)
    assert rerun.returncode == 0, rerun.stderr
    note = f"note: taking over the lock of {lock.parent} left by process {proc.pid}, which is gone"
    assert [line for line in rerun.stderr.splitlines() if line.startswith("note:")] == [note]
    assert not lock.exists()
    check_store(store)


@needs_proc
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_an_interrupted_pool_prebake_stops_its_workers_keeps_its_maps_and_releases_its_lock(
    sig: signal.Signals, scenes_dir: Path, tmp_path: Path
) -> None:
    """Ctrl-C, and SIGTERM as a batch command takes it, while maps are being stored: the stored maps are whole
    and the lock is released (a rerun that completes a partial store is the kill -9 tests')."""
    spec, store, log = scenes_dir / "ball_moving.json", tmp_path / "store", tmp_path / "stderr.txt"
    proc = start_pool_prebake(spec, store, log)
    try:
        while count_rows(store) < 3:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.02)
        started = time.monotonic()
        proc.send_signal(sig)
        proc.wait(timeout=120)
        wait_session_gone(proc.pid)
        took = time.monotonic() - started
    finally:
        with suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    print(f"prebake and its workers gone {took * 1e3:.0f} ms after {sig.name}")
    err = log.read_text()
    assert proc.returncode == 130, err
    assert "interrupted: rerun the same command" in err and "Traceback" not in err
    assert list(store.rglob(".lock")) == [] and not (store / ".prebake" / "ball_moving").exists()
    assert 3 <= check_store(store) < expected_entries(spec, POOL_FRAMES)


def test_a_read_only_index_is_one_error_line_before_any_map_is_baked(
    scenes_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    spec, store = scenes_dir / "ball_moving.json", tmp_path / "store"
    GITree(store).close()  # an empty store
    with read_only(store / "index.sqlite"):
        proc = prebake_here(spec, store, 4, monkeypatch, capfd)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith(f"error: {store}/index.sqlite is read-only: make it")
    assert len(proc.stderr.splitlines()) == 1 and proc.stdout == ""  # not even the plan ("maps to bake")
    assert count_rows(store) == 0 and list((store / "payloads").iterdir()) == []
    assert not (store / ".prebake" / "ball_moving").exists()


def session_commands(sid: int) -> dict[int, bytes]:
    """Command line of each running process of session ``sid``."""
    out = {}
    for pid in session_processes(sid):
        with suppress(OSError):
            out[pid] = Path(f"/proc/{pid}/cmdline").read_bytes()
    return out


@needs_proc
@pytest.mark.slow
def test_kill_9_of_a_ray_prebake_ends_the_local_instance_it_started(scenes_dir: Path, tmp_path: Path) -> None:
    """--executor ray with no cluster to join starts a local Ray instance; after kill -9 of the driver nothing
    of it runs on: Ray ends the GCS, raylet and workers, the driver's watchdog the node's agents."""
    spec, store, log = scenes_dir / "ball_moving.json", tmp_path / "store", tmp_path / "stderr.txt"
    # Its own Ray folder: another test's instance on this machine (its address file) is not one to join. Short:
    # Ray's socket paths must fit in 107 bytes.
    ray_dir = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | {"RAY_TMPDIR": str(ray_dir)}
    with log.open("w") as err:
        proc = subprocess.Popen(
            prebake_cmd(spec, store, 40, "--executor", "ray"),
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,
            env=env,
        )
    try:
        deadline = time.monotonic() + HANG_GUARD_S
        while not any(c.startswith(b"ray::run_ray_job") for c in session_commands(proc.pid).values()):
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)
        ray_processes = session_commands(proc.pid)
        if not any(b"raylet" in c for c in ray_processes.values()):
            pytest.skip("a Ray cluster runs on this machine: --executor ray joined it rather than start one")
        assert any(c.startswith(b"ray::DashboardAgent") for c in ray_processes.values())  # what Ray leaves behind
        killed = time.monotonic()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=120)
        while (left := session_processes(proc.pid)) and time.monotonic() - killed < GONE_S:
            time.sleep(0.05)
        took = time.monotonic() - killed
        print(f"{len(ray_processes)} processes of the local Ray instance gone {took:.1f} s after kill -9")
        assert left == [], {pid: session_commands(proc.pid).get(pid, b"")[:60] for pid in left}
    finally:
        for pid in session_processes(proc.pid):
            with suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        shutil.rmtree(ray_dir, ignore_errors=True)
    check_store(store)
