"""User errors of `cloudbaking-client`: exit 2, one `error:` line naming the culprit, no traceback (Errors).
The server is checked at start, so an unreachable server or a dead link is one line, not a hang. The client
runs in-process under the same error policy (tests.helpers.cli.run_main), except an unreachable server's
case, which runs the installed console script as its own process."""

from __future__ import annotations

import json
import socket
from collections.abc import Callable
from pathlib import Path

import pytest

from network_sim.process import network_sim
from tests.helpers.cli import BIN, Outcome, assert_error_line, run_command, run_main
from tests.helpers.cloud import server_process, write_scenes

Client = Callable[..., Outcome]


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("cli_client_scenes"))


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, scenes_dir: Path):
    with server_process(tmp_path_factory.mktemp("cli_client_store"), scenes_dir, "--max-spp", "16") as url:
        yield url


def client_argv(server: str, out: Path, *args: str, scene: str | None = None) -> list[str]:
    argv = ["cloudbaking-client", "--server", server, "--out", str(out), "--resolution", "64", "--spp", "4"]
    return [*argv, *args] + (["--scene", scene] if scene else [])


@pytest.fixture
def client(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]) -> Client:
    """``cloudbaking-client`` in-process: (server, out, *options, scene=...)."""
    return lambda *args, **scene: run_main(client_argv(*args, **scene), tmp_path, monkeypatch, capfd)


def closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_unreachable_or_malformed_server_url(client: Client, scenes_dir: Path, tmp_path: Path) -> None:
    scene = str(scenes_dir / "ball_moving.json")
    argv = client_argv(f"http://127.0.0.1:{closed_port()}", tmp_path / "o", scene=scene)
    unreachable = run_command([str(BIN / argv[0]), *argv[1:]])  # the installed console script, as a process
    assert_error_line(unreachable, "--server", "cannot connect")
    assert_error_line(client("ftp://127.0.0.1:21", tmp_path / "o", scene=scene), "--server", "ftp://")
    assert not (tmp_path / "o").exists()


def test_a_dead_link_is_one_line_at_start(client: Client, server: str, scenes_dir: Path, tmp_path: Path) -> None:
    with network_sim("proxy", "--upstream", server.removeprefix("http://"), "--rate-mbit", "0") as proxy:
        url = "http://{}:{}".format(*proxy.addr)
        args = ("--connect-timeout", "1", "--read-timeout", "1")
        assert_error_line(
            client(url, tmp_path / "o", *args, scene=str(scenes_dir / "ball_moving.json")), "--server", "no answer"
        )


def test_what_the_server_does_not_serve(client: Client, server: str, scenes_dir: Path, tmp_path: Path) -> None:
    unknown = tmp_path / "not_on_server.json"
    unknown.write_text(
        json.dumps(json.loads((scenes_dir / "ball_static.json").read_text()) | {"name": "not_on_server"})
    )
    (tmp_path / "sphere.obj").write_bytes((scenes_dir / "sphere.obj").read_bytes())
    scene = str(scenes_dir / "ball_moving.json")
    assert_error_line(client(server, tmp_path / "o", scene=str(unknown)), "--scene", "not_on_server")
    assert_error_line(client(server, tmp_path / "o", "--resolution", "100", scene=scene), "--resolution 100")
    assert_error_line(client(server, tmp_path / "o", "--spp", "32", scene=scene), "--spp 32", "max_spp 16")
    assert not (tmp_path / "o").exists()


def test_bad_options(client: Client, server: str, scenes_dir: Path, tmp_path: Path) -> None:
    scene = str(scenes_dir / "ball_moving.json")
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert_error_line(client(server, tmp_path / "o", "--codec", "gif", scene=scene), "--codec", "gif")
    assert_error_line(client(server, tmp_path / "o", "--frames", "0", scene=scene), "--frames")
    assert_error_line(client(server, tmp_path / "o", "--gi-fov", "180", scene=scene), "--gi-fov")
    assert_error_line(client(server, tmp_path / "o", scene=str(tmp_path / "missing.toml")), "missing.toml")
    assert_error_line(client(server, afile, scene=scene), "--out", str(afile))


@pytest.mark.parametrize(
    ("option", "value", "culprit"),
    [
        ("--frames", "1000000000000", "--frames = 1000000000000 is above 100000"),
        ("--orbit-frames", "1000000000000", "--orbit-frames = 1000000000000 is above 100000"),
        ("--resolution", "4096", "--resolution = 4096 is above 2048"),
        ("--spp", "100000", "--spp = 100000 is above 4096"),
        ("--tau", "inf", "--tau = inf is not finite"),
        ("--local-fov", "nan", "--local-fov = nan is not finite"),
        ("--connect-timeout", "inf", "--connect-timeout = inf is not finite"),
        ("--read-timeout", "0", "--read-timeout = 0.0 is below 0.001"),
        ("--deadline", "1e9", "--deadline = 1000000000.0 is above 3600.0"),
        ("--seed", "-1", "--seed = -1 is below 0"),
    ],
)
def test_non_finite_and_huge_values(client: Client, tmp_path: Path, option: str, value: str, culprit: str) -> None:
    """Checked before the server is asked (so no server is needed): one error line naming the option."""
    result = client(f"http://127.0.0.1:{closed_port()}", tmp_path / "o", option, value)
    assert_error_line(result, culprit)
    assert not (tmp_path / "o").exists()
