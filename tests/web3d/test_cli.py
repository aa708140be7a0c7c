"""gigan-web's error policy: one error line naming the option, exit 2, nothing exported, no child started
(docs/architecture.md, Errors). The cases run gigan-web's ``main`` in this process; the taken port runs as a real
process (the installed console script). Its children and signals: test_children.py."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from tests.helpers.cli import check_user_error, run_main, run_script


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


def _model_without_config(folder: Path) -> Path:
    """A model file with no model.json beside it (the page could not encode its inputs)."""
    lone = folder / "lone"
    lone.mkdir()
    (lone / "model.onnx").write_bytes(b"onnx")
    return lone / "model.onnx"
