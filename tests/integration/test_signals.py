"""The signal policy of every command (docs/architecture.md, Errors): SIGTERM is handled exactly like Ctrl-C.

A service (network-sim proxy and server, gigan-web) asked to stop by either signal ends normally: exit 0, no
traceback, no ``interrupted`` line. A batch command (gicore-dataset here; every batch command goes through the
same entry point) stopped part-way keeps what it finished, prints one ``interrupted:`` line and exits 130.
"""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from network_sim.process import network_sim
from tests.helpers.cli import BIN, TIMEOUT_S

SIGNALS = [pytest.param(signal.SIGTERM, id="sigterm"), pytest.param(signal.SIGINT, id="sigint")]


def signal_when(argv: list[str], cwd: Path, ready: Callable[[subprocess.Popen], bool], sig: int) -> tuple[int, str]:
    """Start console script ``argv``, send ``sig`` once ``ready(proc)`` holds; its exit status and stderr."""
    proc = subprocess.Popen(
        [str(BIN / argv[0]), *argv[1:]], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while not ready(proc):
            assert proc.poll() is None, f"{argv[0]} ended before it was ready: {proc.communicate()}"
            assert time.monotonic() < deadline, f"{argv[0]} was not ready within {TIMEOUT_S} s"
            time.sleep(0.05)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, err


def assert_stopped_normally(status: int, err: str) -> None:
    assert status == 0, err
    assert "Traceback" not in err and "interrupted" not in err, err


@pytest.mark.parametrize("sig", SIGNALS)
def test_the_proxy_and_the_endpoint_server_exit_0(sig: int) -> None:
    with network_sim("server") as upstream:
        host, port = upstream.addr
        with network_sim("proxy", "--upstream", f"{host}:{port}", "--delay-ms", "1") as proxy:
            proxy.proc.send_signal(sig)
            assert_stopped_normally(proxy.proc.wait(TIMEOUT_S), proxy.stderr())
        upstream.proc.send_signal(sig)
        assert_stopped_normally(upstream.proc.wait(TIMEOUT_S), upstream.stderr())


@pytest.mark.slow
@pytest.mark.parametrize("sig", SIGNALS)
def test_the_web_viewer_exits_0(sig: int, tmp_path: Path) -> None:
    lines: list[str] = []

    def serving(proc: subprocess.Popen) -> bool:
        assert proc.stdout is not None
        lines.append(proc.stdout.readline())  # blocks until the line comes or the process ends
        return lines[-1].startswith("serving ")

    argv = ["gigan-web", "--scene", "lung_plane", "--frames", "2", "--listen", "127.0.0.1:0", "--assets", "assets"]
    status, err = signal_when(argv, tmp_path, serving, sig)
    assert_stopped_normally(status, err)


@pytest.mark.slow
@pytest.mark.parametrize("sig", SIGNALS)
def test_a_batch_command_exits_130_keeping_its_finished_frames(
    sig: int, tmp_path: Path, sphere_mesh_path: Path
) -> None:
    from gicore.dataset import load_frame

    (tmp_path / "scene.toml").write_text(
        f'name = "s"\n[[objects]]\nname = "ball"\nmesh = "{sphere_mesh_path}"\n'
        "[light]\nposition = [0, 2, 0]\nintensity = 3.0\n"
    )
    argv = ["gicore-dataset", "scene.toml", "--out", "ds", "--train", "200", "--val", "0"]
    argv += ["--resolution", "8", "--spp", "1", "--no-denoise"]
    frames = tmp_path / "ds" / "s" / "train"
    status, err = signal_when(argv, tmp_path, lambda _: len(list(frames.glob("*.npz"))) >= 2, sig)
    assert status == 130, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines[-1] == "interrupted: finished frames are kept: run the same command again to render the rest", err
    assert "Traceback" not in err
    kept = sorted(frames.glob("*.npz"))
    assert 2 <= len(kept) < 200 and not (tmp_path / "ds" / "s" / ".lock").exists()
    for path in kept:
        load_frame(path)  # whole
