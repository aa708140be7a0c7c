"""gigan-web as a process, stopped while it works (real processes on ephemeral ports): SIGTERM during a forwarded
miss answers the browser 503 "stopping", as the cloud-baking server does, and exits 0 without a traceback;
Ctrl-C or SIGTERM while the modules still load exits as quietly."""

from __future__ import annotations

import signal
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest

from tests.helpers.cli import interpreter_started_marker
from tests.web3d.test_children import HANG_GUARD_S, assert_stopped_normally, viewer
from web3d.site import WEB_DIR

pytestmark = pytest.mark.skipif(
    not (WEB_DIR / "node_modules" / "onnxruntime-web").is_dir(), reason="web3d/static/node_modules is missing"
)


@dataclass
class Silent:
    """A server that reads requests and never answers: its URL, an event set once a request arrived, and the
    connections it accepted."""

    url: str
    arrived: threading.Event = field(default_factory=threading.Event)
    held: list[socket.socket] = field(default_factory=list)


@contextmanager
def silent_upstream() -> Iterator[Silent]:
    """A :class:`Silent` server (a miss path-traced for ever, a health check never answered) on a free port."""
    listener = socket.create_server(("127.0.0.1", 0))
    silent = Silent(f"http://127.0.0.1:{listener.getsockname()[1]}")

    def accept() -> None:
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:  # closed: the test is over
                return
            silent.held.append(conn)
            if conn.recv(65536):
                silent.arrived.set()

    threading.Thread(target=accept, daemon=True).start()
    try:
        yield silent
    finally:
        listener.close()
        for conn in silent.held:
            conn.close()


@pytest.mark.slow
def test_sigterm_during_a_forwarded_miss_answers_503_stopping(tmp_path: Path) -> None:
    with silent_upstream() as upstream, viewer(["--scene", "lung_plane", "--server", upstream.url], tmp_path) as run:
        url = run.read_until("serving").split(" at ")[1].split()[0].rstrip("/")
        answers: list[httpx.Response] = []
        post = threading.Thread(
            target=lambda: answers.append(httpx.post(f"{url}/v1/gimap", json={}, timeout=HANG_GUARD_S))
        )
        post.start()
        assert upstream.arrived.wait(HANG_GUARD_S), "the request never reached the upstream"
        err = run.stop_and_read(signal.SIGTERM)
        post.join(HANG_GUARD_S)
    (answer,) = answers
    assert answer.status_code == 503 and "stopping" in answer.json()["detail"], answer.text
    assert_stopped_normally(run.proc.returncode, err)


@pytest.mark.parametrize(("sig", "delay_s"), [(signal.SIGINT, d) for d in (0.1, 0.3, 0.5, 0.7, 0.9)] + [
    (signal.SIGTERM, d) for d in (0.05, 0.3)])  # fmt: skip
def test_a_stop_while_it_loads_exits_quietly(tmp_path: Path, sig: int, delay_s: float) -> None:
    """Ctrl-C or SIGTERM within the first second of its own code (importing its modules, computing its options'
    defaults, exporting the scene) stops it as a stop once it serves does: exit 0, nothing on stderr."""
    env, started = interpreter_started_marker(tmp_path)
    with viewer(["--scene", "lung_plane", "--no-cloud"], tmp_path, env) as run:
        deadline = time.monotonic() + HANG_GUARD_S
        while not started.exists():
            assert time.monotonic() < deadline and run.proc.poll() is None, "the interpreter never started"
            time.sleep(0.005)
        time.sleep(delay_s)
        err = run.stop_and_read(sig)
    assert_stopped_normally(run.proc.returncode, err)
    assert err == ""
