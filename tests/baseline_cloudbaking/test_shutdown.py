"""Stopping cloudbaking-server: SIGTERM as Ctrl-C, the miss being rendered finished, stored and answered, the
misses still waiting answered 503, exit 0; a render past the graceful timeout abandoned unstored; kill -9 in
the middle of bakes leaves no torn entry; a closed GI tree refuses every call instead of reopening."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import httpx
import numpy as np
import pytest

from baseline_cloudbaking import payload_files
from baseline_cloudbaking.store import GITree
from baseline_cloudbaking.store_errors import StoreClosed
from baseline_cloudbaking.viewpoints import MapKey, Viewpoint
from tests.helpers.cloud import BIN, gimap_body, write_scenes

#: Guards against a hung test only (a render on a busy 2-core machine takes seconds).
HANG_S = 120.0


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("stop_scenes"))


@contextmanager
def running(store: Path, scenes: Path, *args: str) -> Iterator[tuple[subprocess.Popen, str, Path]]:
    """``cloudbaking-server`` on an ephemeral port: the process, its URL once it answers, its stderr file."""
    stderr = store.parent / f"{store.name}.stderr"
    argv = [str(BIN / "cloudbaking-server"), "--port", "0", "--store", str(store), "--scenes", str(scenes), *args]
    with stderr.open("wb") as err:
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        url = proc.stdout.readline().split()[-1]
        wait_for(lambda: httpx.get(f"{url}/v1/health", timeout=10).status_code == 200)
        yield proc, url, stderr
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=HANG_S)


def wait_for(condition) -> None:
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        try:
            if condition():
                return
        except httpx.TransportError:
            pass
        time.sleep(0.05)
    raise AssertionError("the server did not get there")


def pending(url: str) -> int:
    return httpx.get(f"{url}/v1/stats", timeout=HANG_S).json()["misses_pending"]


def post(url: str, body: dict) -> httpx.Response:
    return httpx.post(f"{url}/v1/gimap", json=body, timeout=HANG_S)


#: A miss that renders for a second or more on CPU (a renderer compiled, then 512² at 64 spp: far longer than the
#: two requests the test sends before its SIGTERM), and one queued behind it.
RENDERING = gimap_body(eye=(1.6, 1.1, 1.2), resolution=512, spp=64)
WAITING = gimap_body(eye=(-1.6, 1.1, 1.2), resolution=256, spp=256)


def stopping_detail(response: httpx.Response) -> None:
    assert response.status_code == 503 and int(response.headers["retry-after"]) >= 1, response.text
    (detail,) = response.json()["detail"]
    assert detail["loc"] == ["server"] and detail["type"] == "stopping" and "stopping" in detail["msg"]


@pytest.mark.slow
def test_a_miss_rendering_at_sigterm_is_stored_and_answered_then_exit_0(tmp_path: Path, scenes_dir: Path) -> None:
    store = tmp_path / "store"
    with running(store, scenes_dir, "--graceful-timeout-s", str(HANG_S)) as (proc, url, stderr):
        with ThreadPoolExecutor(2) as pool:
            rendering = pool.submit(post, url, RENDERING)
            wait_for(lambda: pending(url) == 1)
            waiting = pool.submit(post, url, WAITING)
            wait_for(lambda: pending(url) == 2)
            proc.send_signal(signal.SIGTERM)
            stopping_detail(waiting.result())  # not started: answered at once
            answered = rendering.result()
        assert proc.wait(timeout=HANG_S) == 0
    assert answered.status_code == 200 and answered.headers["x-gimap-hit"] == "0", answered.text
    assert "Traceback" not in stderr.read_text()
    with GITree(store) as tree:
        assert tree.verify() == [] and set(tree.swept.values()) == {0}
        [entry] = tree.entries()
        assert entry.view.eye == pytest.approx(RENDERING["camera"]["eye"])
        assert tree.payload_by_sha(entry.sha) is not None


def test_a_render_past_the_graceful_timeout_at_ctrl_c_is_abandoned_unstored_then_exit_0(
    tmp_path: Path, scenes_dir: Path
) -> None:
    """SIGINT as SIGTERM. A 512² map at 256 spp (and its renderer's compilation) takes far longer than 50 ms: its
    client gets 503, the process ends without waiting for the render, and the GI tree stays consistent without
    it."""
    store = tmp_path / "store"
    with running(store, scenes_dir, "--graceful-timeout-s", "0.05") as (proc, url, stderr):
        with ThreadPoolExecutor(1) as pool:
            rendering = pool.submit(post, url, gimap_body(resolution=512, spp=256))
            wait_for(lambda: pending(url) == 1)
            proc.send_signal(signal.SIGINT)
            stopping_detail(rendering.result())
        assert proc.wait(timeout=HANG_S) == 0
    log = stderr.read_text()
    assert "abandoned" in log and "Traceback" not in log, log
    with GITree(store) as tree:
        assert tree.entries() == [] and tree.verify() == []


@pytest.mark.slow
def test_kill_9_in_the_middle_of_bakes_leaves_no_torn_entry(tmp_path: Path, scenes_dir: Path) -> None:
    """Killed at two moments of a run of misses: each reopening finds every indexed payload whole and no file
    unindexed after its sweep."""
    store = tmp_path / "store"
    for round_, delay in enumerate((0.0, 1.0)):
        with running(store, scenes_dir) as (proc, url, _):
            bodies = [gimap_body(eye=(1.8 * np.sin(a), 1.1, 1.8 * np.cos(a))) for a in np.linspace(-1, 1, 6) + round_]
            with ThreadPoolExecutor(len(bodies)) as pool:
                futures = [pool.submit(post, url, body) for body in bodies]
                wait_for(lambda: pending(url) >= 1)
                time.sleep(delay)  # varies the moment of the kill, bounds nothing
                proc.kill()
                for future in futures:  # answered before the kill, or cut off
                    assert future.exception() is None or isinstance(future.exception(), httpx.TransportError)
        with GITree(store) as tree:
            assert tree.verify() == []
            indexed = {e.sha for e in tree.entries()}
            on_disk = {p.name.removesuffix(".gim") for p in (store / "payloads").glob("*/*.gim")}
            assert on_disk == indexed and not list((store / "payloads").glob("*/*.tmp*"))


# -- the GI tree itself --------------------------------------------------------------------------------------
def key() -> MapKey:
    return MapKey("s", (0, 0, 0), 64, 90.0, "jpeg", 4, False)


VIEW = Viewpoint.look_at((0.0, 1.0, 2.0), (0.0, 0.5, 0.0))


def test_a_closed_tree_refuses_every_call_and_never_reopens(tmp_path: Path) -> None:
    tree = GITree(tmp_path / "store")
    tree.register_scene("s", "sha-s", 0.25)
    tree.insert(key(), VIEW, b"payload")
    sha = tree.entries()[0].sha
    assert tree.lookup(key(), VIEW) is not None
    assert tree.lookup(key(), VIEW, io=False) is not None  # now answered from memory
    tree.close()
    calls = {
        "lookup": lambda: tree.lookup(key(), VIEW),
        "lookup from memory": lambda: tree.lookup(key(), VIEW, io=False),
        "insert": lambda: tree.insert(key(), VIEW, b"other"),
        "payload_by_sha": lambda: tree.payload_by_sha(sha),
        "entries": tree.entries,
        "stats": tree.stats,
        "register_scene": lambda: tree.register_scene("t", "sha-t", None),
        "verify": tree.verify,
    }
    for name, call in calls.items():
        with pytest.raises(StoreClosed, match="is closed"):
            call()
        assert not tree.index._connections, name  # nothing reopened behind the caller's back
    tree.close()  # closing again does nothing


def test_close_waits_for_an_insert_in_progress(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A bake finishing on another thread while the tree closes: the insert completes, then the tree closes."""
    writing, release = threading.Event(), threading.Event()
    write = payload_files.atomic_write_bytes

    def slow_write(path: Path, data: bytes) -> None:
        writing.set()
        release.wait(HANG_S)
        write(path, data)

    monkeypatch.setattr(payload_files, "atomic_write_bytes", slow_write)
    tree = GITree(tmp_path / "store")
    tree.register_scene("s", "sha-s", 0.25)
    inserted: list[int | None] = []
    inserter = threading.Thread(target=lambda: inserted.append(tree.insert(key(), VIEW, b"payload")))
    inserter.start()
    assert writing.wait(HANG_S)
    closer = threading.Thread(target=tree.close)
    closer.start()
    closer.join(0.2)
    assert closer.is_alive()  # held by the insert
    release.set()
    inserter.join(HANG_S)
    closer.join(HANG_S)
    assert inserted and inserted[0] is not None
    with GITree(tmp_path / "store") as again:
        assert len(again.entries()) == 1 and again.verify() == []
