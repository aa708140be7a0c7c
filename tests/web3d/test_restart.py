"""gigan-web's children that end while it serves (real processes, SIGKILL from outside): each end is said once on
stderr and the child started again (a server with the proxy in front of it), so the page's next request is
answered as before; past the restart limit a request is 503 with one line that names no internal address."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import httpx
import pytest

from tests.web3d.test_children import HANG_GUARD_S, Viewer, assert_stopped_normally, viewer
from web3d.children import MAX_RESTARTS
from web3d.site import WEB_DIR

pytestmark = pytest.mark.skipif(
    not (WEB_DIR / "node_modules" / "onnxruntime-web").is_dir(), reason="web3d/static/node_modules is missing"
)
PROXY = "network-sim proxy lan -> given store"
SERVER = "cloudbaking-server, given store"


def kill(run: Viewer, child: str, killed: list[int]) -> None:
    """SIGKILL the running ``child`` gigan-web started (the one whose line starts with ``child``; its lines are
    read until one that has not ended comes), add its pid to ``killed`` and wait until it has ended."""
    while ended(pid := [pid for name, (_, pid) in run.children().items() if name.startswith(child)][-1]):
        run.read_until(child)
    os.kill(pid, signal.SIGKILL)
    killed.append(pid)
    deadline = time.monotonic() + HANG_GUARD_S
    while ended(pid) is False:
        assert time.monotonic() < deadline, f"{child} (pid {pid}) did not end"
        time.sleep(0.05)


def ended(pid: int) -> bool:
    """Whether ``pid`` has ended (a zombie not yet reaped by gigan-web, or gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def refused_by_the_server(url: str) -> None:
    """A request the server refuses itself (no scene): it went through gigan-web, a proxy and a server."""
    r = httpx.post(f"{url}/v1/gimap", json={}, timeout=HANG_GUARD_S)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "scene"], r.text


@pytest.mark.slow
def test_a_child_that_ends_is_said_once_and_started_again_up_to_a_limit(tmp_path: Path) -> None:
    with viewer(["--scene", "lung_plane", "--profiles", "lan"], tmp_path) as run:
        url = run.read_until("serving").split(" at ")[1].split()[0].rstrip("/")
        killed: list[int] = []
        kill(run, PROXY, killed)
        refused_by_the_server(url)  # the request that notices it waits for the new proxy
        kill(run, SERVER, killed)
        refused_by_the_server(url)
        status = httpx.get(f"{url}/v1/status", timeout=HANG_GUARD_S).json()
        assert status["profiles"] == {"lan": "up"} and status["stores"] == {"given": "up"}
        for _ in range(MAX_RESTARTS):  # the proxy's first end above was its first restart
            kill(run, PROXY, killed)
        r = httpx.post(f"{url}/v1/gimap", json={}, timeout=HANG_GUARD_S)
        assert r.status_code == 503 and "restart gigan-web" in r.json()["detail"], r.text
        assert "127.0.0.1" not in r.text and "http" not in r.text
        assert httpx.get(f"{url}/v1/status", timeout=HANG_GUARD_S).json()["profiles"] == {"lan": "down"}
        err = run.stop_and_read(signal.SIGTERM)
    assert_stopped_normally(run.proc.returncode, err)
    said = [line for line in err.splitlines() if line.startswith("gigan-web: ")]
    assert len(said) == len(killed) and all(f"(pid {pid})" in line for pid, line in zip(killed, said)), err
    assert said[-1].endswith("restart gigan-web"), err
