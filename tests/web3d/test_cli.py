"""gigan-web's error policy: one error line naming the option, exit 2, nothing exported, no child started
(docs/architecture.md, Errors). The cases run gigan-web's ``main`` in this process; the taken port runs as a real
process (the installed console script). Its children and signals: test_children.py."""

from __future__ import annotations

import signal
import socket
from pathlib import Path

import httpx
import pytest

from tests.helpers.cli import check_user_error, run_main, run_script
from tests.web3d.test_children import HANG_GUARD_S, assert_stopped_normally, viewer


def _has_ipv6_loopback() -> bool:
    try:
        socket.create_server(("::1", 0), family=socket.AF_INET6).close()
    except OSError:
        return False
    return True


IPV6 = _has_ipv6_loopback()


def test_bad_options_are_one_error_line_and_write_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    cases = [
        (["--server", "ftp://host"], "--server"),
        (["--codec", "exr-half"], "--codec"),
        (["--listen", "nowhere"], "--listen"),
        (["--scene", "no_such_scene"], "no_such_scene"),
        (["--model", str(tmp_path / "missing.onnx")], "--model"),
        (["--model", str(_model_without_config(tmp_path))], "model.json"),
        (["--profiles", "lan,moon"], "moon"),
        (["--store", str(tmp_path / "no_such_store")], "--store"),
        (["--server", "http://127.0.0.1:1", "--store", str(tmp_path)], "--store"),
        (["--server", "http://127.0.0.1:1", "--profiles", "lan"], "--profiles"),
        (["--server", "http://127.0.0.1:1", "--no-cloud"], "--server"),
        (["--no-cloud", "--store", str(tmp_path)], "--no-cloud"),
    ]
    for argv, culprit in cases:
        check_user_error(run_main(["gigan-web", *argv], tmp_path, monkeypatch, capfd), culprit)


def test_a_taken_port_is_one_error_line_before_anything_is_written(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        outcome = run_script(["gigan-web", "--listen", f"127.0.0.1:{taken.getsockname()[1]}"], tmp_path)
    check_user_error(outcome, "--listen")
    assert "pick a free port" in outcome.stderr


def test_an_address_not_of_this_machine_is_not_called_a_taken_port(tmp_path: Path) -> None:
    for listen in ("192.0.2.1:0", "no-such-host.invalid:0"):  # TEST-NET-1, and a name that never resolves
        outcome = run_script(["gigan-web", "--listen", listen], tmp_path)
        check_user_error(outcome, "--listen")
        assert "an address of this machine" in outcome.stderr and "free port" not in outcome.stderr, outcome.stderr


@pytest.mark.skipif(not IPV6, reason="this machine has no IPv6 loopback")
def test_it_serves_on_a_bracketed_ipv6_address(tmp_path: Path) -> None:
    with viewer(["--scene", "lung_plane", "--no-cloud", "--listen", "[::1]:0"], tmp_path) as run:
        url = run.read_until("serving").split(" at ")[1].split()[0].rstrip("/")
        assert url.startswith("http://[::1]:")
        assert httpx.get(f"{url}/config.json", timeout=HANG_GUARD_S).json()["scene"] == "lung_plane"
        err = run.stop_and_read(signal.SIGTERM)
    assert_stopped_normally(run.proc.returncode, err)


def _model_without_config(folder: Path) -> Path:
    """A model file with no model.json beside it (the page could not encode its inputs)."""
    lone = folder / "lone"
    lone.mkdir()
    (lone / "model.onnx").write_bytes(b"onnx")
    return lone / "model.onnx"
