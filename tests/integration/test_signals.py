"""The signal policy of every command (docs/architecture.md, Errors): SIGTERM is handled exactly like Ctrl-C.

A service (network-sim proxy and server, cloudbaking-server) asked to stop by either signal ends normally: exit 0,
no traceback, no ``interrupted`` line, also while its modules still load; gigan-web's stops, with its children, are
tests/web3d/test_children.py's and test_stop.py's. A batch command
(gicore-dataset here; every batch command goes through the same entry point) stopped part-way by SIGTERM keeps
what it finished, prints one ``interrupted:`` line and exits 130; its Ctrl-C, and the rerun that resumes, is
tests/integration/test_cli_errors.py's ``test_interrupted_dataset_keeps_whole_frames_and_resumes``.
"""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from network_sim.process import network_sim
from tests.helpers.cli import TIMEOUT_S, signal_after_start, signal_when

SIGNALS = [pytest.param(signal.SIGTERM, id="sigterm"), pytest.param(signal.SIGINT, id="sigint")]


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


@pytest.mark.parametrize("sig", SIGNALS)
@pytest.mark.parametrize("service", ["cloudbaking-server", "network-sim proxy"])
def test_a_service_stopped_while_its_modules_load_exits_0(tmp_path: Path, service: str, sig: int) -> None:
    """At delays from CPython's own start that land in its imports (a Ctrl-C there was a traceback, a SIGTERM
    killed it, -15), in its options' parsing and once it serves. (The first milliseconds, while the import system
    finds the package, are before any of its code, as CPython's own start is.)"""
    with network_sim("server") as upstream:
        host, port = upstream.addr
        argv = {
            "cloudbaking-server": ["cloudbaking-server", "--port", "0", "--store", "store"],
            "network-sim proxy": ["network-sim", "proxy", "--upstream", f"{host}:{port}"],
        }[service]
        for delay_s in (0.05, 0.1, 0.2, 0.35, 0.6):
            status, err = signal_after_start(argv, tmp_path, sig, delay_s)
            assert_stopped_normally(status, err)


@pytest.mark.parametrize("sig", SIGNALS)
def test_a_batch_command_of_the_same_script_stopped_while_it_loads_is_interrupted(tmp_path: Path, sig: int) -> None:
    """network-sim's self-test is a batch command: stopped while it loads or runs, exit 130 and one line."""
    for delay_s in (0.05, 0.3):
        status, err = signal_after_start(["network-sim", "selftest", "--out", "out"], tmp_path, sig, delay_s)
        assert status == 130 and "Traceback" not in err, err
        assert [line for line in err.splitlines() if line.strip()][-1].startswith("interrupted: "), err


@pytest.mark.slow
def test_a_batch_command_stopped_by_sigterm_exits_130_keeping_its_finished_frames(
    tmp_path: Path, sphere_mesh_path: Path
) -> None:
    from gicore.dataset import load_frame

    (tmp_path / "scene.toml").write_text(
        f'name = "s"\n[[objects]]\nname = "ball"\nmesh = "{sphere_mesh_path}"\n'
        "[light]\nposition = [0, 2, 0]\nintensity = 3.0\n"
    )
    argv = ["gicore-dataset", "scene.toml", "--out", "ds", "--train", "200", "--val", "0"]
    argv += ["--resolution", "8", "--spp", "1", "--no-denoise"]
    frames = tmp_path / "ds" / "s" / "train"
    status, err = signal_when(argv, tmp_path, lambda _: len(list(frames.glob("*.npz"))) >= 2, signal.SIGTERM)
    assert status == 130, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines[-1] == "interrupted: finished frames are kept: run the same command again to render the rest", err
    assert "Traceback" not in err
    kept = sorted(frames.glob("*.npz"))
    assert 2 <= len(kept) < 200 and not (tmp_path / "ds" / "s" / ".lock").exists()
    for path in kept:
        load_frame(path)  # whole
