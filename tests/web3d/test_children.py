"""gigan-web's own cloud side (real processes): a cloudbaking-server on the given store and a network-sim proxy per
profile before the page is served, a cold store's server and proxy started on its first request, each request
reaching the chosen profile's proxy of the chosen store's server; and no child left behind: not after SIGTERM,
SIGKILL or Ctrl-C (SIGINT to gigan-web alone, while it serves or while its children start), not after a child failed to
start; a stop by SIGTERM or SIGINT is a service's (exit 0, silent). Every process gigan-web starts stays in its
session, so the session's members are what it left."""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

import web3d.children
from web3d.children import ChildCloud
from web3d.site import WEB_DIR
from web3d.upstreams import Unavailable

BIN = Path(sys.executable).parent
#: Waits for a process or a line: a start exports the scene and imports the renderer (seconds on an idle machine).
HANG_GUARD_S = 240.0
CHILD = re.compile(r"^(.+): (http://\S+) \(pid (\d+)\)$")

pytestmark = pytest.mark.skipif(
    not (WEB_DIR / "node_modules" / "onnxruntime-web").is_dir(), reason="web3d/static/node_modules is missing"
)


def session_members(sid: int) -> list[int]:
    """Live processes (not zombies) of session ``sid``."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:  # ended while listed
            continue
        state, _, _, session = text[text.rindex(")") + 2 :].split()[:4]
        if int(session) == sid and state != "Z":
            members.append(int(stat.parent.name))
    return members


class Viewer:
    """A ``gigan-web`` process in its own session, and the stdout lines it printed."""

    def __init__(self, argv: list[str], cwd: Path, env: dict[str, str] | None = None) -> None:
        exe = [str(BIN / "gigan-web"), "--listen", "127.0.0.1:0", "--assets", str(cwd / "assets"), *argv]
        self.proc = subprocess.Popen(
            exe, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True, env=env
        )
        self.lines: list[str] = []
        self._buffer = b""

    def read_until(self, prefix: str) -> str:
        """Stdout lines up to one starting with ``prefix`` (returned); AssertionError if it ends first."""
        assert self.proc.stdout is not None
        deadline = time.monotonic() + HANG_GUARD_S
        while True:
            while b"\n" in self._buffer:
                line, _, self._buffer = self._buffer.partition(b"\n")
                self.lines.append(line.decode())
                if self.lines[-1].startswith(prefix):
                    return self.lines[-1]
            left = deadline - time.monotonic()
            assert left > 0, f"no {prefix!r} line within {HANG_GUARD_S} s: {self.lines}"
            if select.select([self.proc.stdout], [], [], left)[0]:
                data = os.read(self.proc.stdout.fileno(), 65536)
                assert data, f"gigan-web ended before {prefix!r}: {self.lines} {self.stop_and_read()}"
                self._buffer += data

    def children(self) -> dict[str, tuple[str, int]]:
        """The children it reported: their line's start (``cloudbaking-server, given store``...) -> (URL, pid)."""
        found = {}
        for line in self.lines:
            match = CHILD.match(line)
            if match:
                found[match.group(1)] = (match.group(2), int(match.group(3)))
        return found

    def stop_and_read(self, sig: int | None = None) -> str:
        """Send ``sig`` (if any), wait for the exit; its stderr."""
        if sig is not None:
            self.proc.send_signal(sig)
        _, err = self.proc.communicate(timeout=HANG_GUARD_S)
        return err.decode()


def assert_stopped_normally(status: int, err: str) -> None:
    """A service's stop (docs/architecture.md, Errors): exit 0, no traceback, no ``interrupted`` line."""
    assert status == 0 and "Traceback" not in err and "interrupted" not in err, err


@contextmanager
def viewer(argv: list[str], cwd: Path, env: dict[str, str] | None = None) -> Iterator[Viewer]:
    run = Viewer(argv, cwd, env)
    try:
        yield run
    finally:
        if run.proc.poll() is None:  # the test failed: leave nothing running
            os.killpg(run.proc.pid, signal.SIGKILL)
            run.proc.wait()


@pytest.mark.slow
def test_children_serve_each_profile_and_store_and_sigterm_stops_them_all(tmp_path: Path) -> None:
    store = tmp_path / "store"
    store.mkdir()
    with viewer(["--scene", "lung_plane", "--store", str(store), "--profiles", "lan,wan"], tmp_path) as run:
        url = run.read_until("serving").split(" at ")[1].split()[0].rstrip("/")
        given = run.children()
        assert [k.split(" ->")[0] for k in given] == [
            f"cloudbaking-server, given store {store}",
            "network-sim proxy lan",
            "network-sim proxy wan",
        ]
        status = httpx.get(f"{url}/v1/status", timeout=HANG_GUARD_S).json()
        assert status == {
            "profiles": {"lan": "up", "wan": "up"},
            "stores": {"given": "up", "cold": "idle"},
            "scene": "lung_plane",
        }
        config = httpx.get(f"{url}/config.json").json()
        assert (config["profiles"], config["stores"]) == (["lan", "wan"], ["given", "cold"])
        for query, profile, store_state in [("?profile=wan", "wan", "given"), ("?store=cold", "lan", "cold")]:
            # a request the server refuses (no scene, no camera): its own 422, through the chosen proxy
            r = httpx.post(f"{url}/v1/gimap{query}", json={}, timeout=HANG_GUARD_S)
            assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "scene"], r.text
            assert (r.headers["x-profile"], r.headers["x-store"]) == (profile, store_state)
        run.read_until("network-sim proxy lan -> cold store")
        cold = next(k for k in run.children() if k.startswith("cloudbaking-server, cold store "))
        cold_store = Path(cold.removeprefix("cloudbaking-server, cold store "))
        assert cold_store.is_dir()
        status = httpx.get(f"{url}/v1/status", timeout=HANG_GUARD_S).json()
        assert status["stores"] == {"given": "up", "cold": "up"}
        assert len(session_members(run.proc.pid)) == 1 + 5  # gigan-web, two servers, three proxies
        err = run.stop_and_read(signal.SIGTERM)
        assert_stopped_normally(run.proc.returncode, err)
    assert session_members(run.proc.pid) == []
    assert not cold_store.exists() and store.is_dir()  # the temporary store removed, the given one kept


@pytest.mark.parametrize(
    "when,profiles",
    # starting: three proxies still to start once the server's line is out, so the SIGINT lands among them
    [pytest.param("starting", "lan,wan,lte", id="starting"), pytest.param("serving", "lan", id="serving")],
)
def test_ctrl_c_leaves_no_child(tmp_path: Path, when: str, profiles: str) -> None:
    """SIGINT to gigan-web alone (a terminal's Ctrl-C reaches the whole group; this is the harder case)."""
    with viewer(["--scene", "lung_plane", "--profiles", profiles], tmp_path) as run:
        run.read_until("cloudbaking-server" if when == "starting" else "serving")
        err = run.stop_and_read(signal.SIGINT)
        assert_stopped_normally(run.proc.returncode, err)
    assert session_members(run.proc.pid) == []
    (server,) = [k for k in run.children() if k.startswith("cloudbaking-server")]
    assert not Path(server.removeprefix("cloudbaking-server, given store ")).exists()  # the temporary store


def temporary(tmp: Path) -> list[Path]:
    """The temporary stores in the folder ``tmp`` (gigan-web's TMPDIR)."""
    return sorted(tmp.glob("gigan-web-*-store-*"))


@pytest.mark.slow
def test_sigkill_leaves_no_child_and_the_next_start_removes_its_store(tmp_path: Path) -> None:
    """SIGKILL runs no cleanup in gigan-web: the kernel signals its children (parent-death signal), and they stop;
    the temporary store it leaves is removed by the next gigan-web that starts (not that of a run still alive)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    alive = tmp / f"gigan-web-{os.getpid()}-given-store-alive"  # this test's process runs
    alive.mkdir()
    env = os.environ | {"TMPDIR": str(tmp)}
    with viewer(["--scene", "lung_plane", "--profiles", "lan"], tmp_path, env) as run:
        run.read_until("serving")
        assert len(session_members(run.proc.pid)) == 1 + 2  # gigan-web, the server, the proxy
        run.proc.kill()
        run.proc.wait()
        deadline = time.monotonic() + HANG_GUARD_S
        while session_members(run.proc.pid) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert session_members(run.proc.pid) == []
    (killed,) = set(temporary(tmp)) - {alive}
    with viewer(["--scene", "lung_plane", "--profiles", "lan"], tmp_path, env) as second:
        second.read_until("serving")
        (started,) = set(temporary(tmp)) - {alive}
        assert started != killed and not killed.exists()
        assert_stopped_normally(0, second.stop_and_read(signal.SIGTERM))
    assert temporary(tmp) == [alive]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_while_the_server_starts_leaves_no_store(tmp_path: Path, sig: int) -> None:
    """The temporary store is made just before its server starts, and that server makes it again if it is gone:
    a stop then waits for the start and stops the server before the folder is removed."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    with viewer(["--scene", "lung_plane", "--profiles", "lan"], tmp_path, os.environ | {"TMPDIR": str(tmp)}) as run:
        deadline = time.monotonic() + HANG_GUARD_S
        while not temporary(tmp):
            assert time.monotonic() < deadline and run.proc.poll() is None, "no temporary store was made"
            time.sleep(0.01)
        err = run.stop_and_read(sig)
        assert_stopped_normally(run.proc.returncode, err)
    assert session_members(run.proc.pid) == [] and temporary(tmp) == []


def test_a_server_that_does_not_start_is_one_error_line(tmp_path: Path) -> None:
    env = os.environ | {"CLOUDBAKING_NO_SUCH_SETTING": "1"}  # the server refuses an unknown setting
    with viewer(["--scene", "lung_plane", "--profiles", "lan"], tmp_path, env) as run:
        err = run.stop_and_read()
    lines = [line for line in err.splitlines() if line.strip()]
    assert run.proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: cloudbaking-server"), err
    assert "CLOUDBAKING_NO_SUCH_SETTING" in lines[0]
    assert session_members(run.proc.pid) == []


def test_a_proxy_that_does_not_start_stops_the_server(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A start that fails half-way (the server up, a proxy refused) leaves nothing running."""
    real = web3d.children.proxy
    monkeypatch.setattr(web3d.children, "proxy", lambda up, *args, **kwargs: real(up, *args, "--no-such", **kwargs))
    lines: list[str] = []
    with pytest.raises(Unavailable, match="network-sim proxy lan did not start"):
        with ChildCloud(("lan",), report=lines.append):
            pass
    (server,) = [CHILD.match(line) for line in lines]
    assert server is not None and not Path(f"/proc/{server.group(3)}").exists()  # stopped and reaped
    assert not Path(server.group(1).removeprefix("cloudbaking-server, given store ")).exists()
