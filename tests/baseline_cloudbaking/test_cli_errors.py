"""User errors of `cloudbaking-server` and `cloudbaking-prebake`: exit 2, one `error:` line naming the
culprit, no traceback (docs/architecture.md, Errors). The commands run in-process under the same error policy
(tests.helpers.cli.run_main); test_server_hardening runs each as its own process."""

from __future__ import annotations

import json
import socket
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.helpers.cli import Outcome, assert_error_line, run_main
from tests.helpers.cloud import write_scenes

Command = Callable[..., Outcome]


@pytest.fixture(scope="module")
def scenes_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_scenes(tmp_path_factory.mktemp("cli_scenes"))


@pytest.fixture
def prebake(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]) -> Command:
    return lambda *args: run_main(["cloudbaking-prebake", *args], tmp_path, monkeypatch, capfd)


@pytest.fixture
def server(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]) -> Command:
    return lambda *args: run_main(["cloudbaking-server", *args], tmp_path, monkeypatch, capfd)


def test_prebake_unknown_scene(prebake: Command, tmp_path: Path) -> None:
    assert_error_line(prebake("no_such_scene", "--store", str(tmp_path / "s")), "no_such_scene")


def test_prebake_invalid_spec_file(prebake: Command, tmp_path: Path) -> None:
    bad = tmp_path / "broken.json"
    bad.write_text(json.dumps({"name": "broken", "objects": [], "light": {"position": [0, 1, 0], "intensity": -1}}))
    assert_error_line(prebake(str(bad), "--store", str(tmp_path / "s")), "broken.json", "objects")


def test_prebake_bad_options(prebake: Command, tmp_path: Path) -> None:
    store = str(tmp_path / "s")
    assert_error_line(prebake("lung_plane", "--store", store, "--codec", "gif"), "--codec", "gif")
    assert_error_line(prebake("lung_plane", "--store", store, "--frames", "0"), "--frames")
    assert_error_line(prebake("lung_plane", "--store", store, "--resolution", "100000"), "--resolution")
    assert_error_line(prebake("lung_plane"), "--store")
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert_error_line(prebake("lung_plane", "--store", str(afile)), "--store", str(afile))


@pytest.mark.parametrize(
    ("option", "value", "culprit"),
    [
        ("--tolerance-p", "inf", "--tolerance-p = inf is not finite"),
        ("--tolerance-p", "-1", "--tolerance-p = -1.0 is below 0.0"),
        ("--tolerance-deg", "nan", "--tolerance-deg = nan is not finite"),
        ("--tolerance-deg", "200", "--tolerance-deg = 200.0 is above 180.0"),
        ("--light-cell", "inf", "--light-cell = inf is not finite"),
        ("--light-cell", "0", "--light-cell = 0.0 is below 1e-06"),
        ("--fov", "inf", "--fov = inf is not finite"),
        ("--frames", "1000000000000", "--frames = 1000000000000 is above 100000"),
        ("--spp", "100000", "--spp = 100000 is above 4096"),
        ("--seed", "-1", "--seed = -1 is below 0"),
        ("--workers", "100000", "--workers"),
    ],
)
def test_prebake_refuses_non_finite_and_huge_values(
    prebake: Command, tmp_path: Path, option: str, value: str, culprit: str
) -> None:
    """Every float is finite and every count bounded: one error line before anything is read or written."""
    store = tmp_path / "s"
    assert_error_line(prebake("lung_plane", "--store", str(store), option, value), culprit)
    assert not store.exists()


def test_prebake_refuses_a_store_baked_from_another_spec(prebake: Command, scenes_dir: Path, tmp_path: Path) -> None:
    store = tmp_path / "s"
    spec = tmp_path / "ball.json"
    data = json.loads((scenes_dir / "ball_static.json").read_text())
    data["objects"][0]["mesh"] = str(scenes_dir / "sphere.obj")
    spec.write_text(json.dumps(data))
    ok = prebake(str(spec), "--store", str(store), "--frames", "1", "--resolution", "16", "--spp", "1")
    assert ok.returncode == 0, ok.stderr
    spec.write_text(json.dumps(data | {"environment": "cornell_box"}))
    assert_error_line(
        prebake(str(spec), "--store", str(store), "--frames", "1", "--resolution", "16", "--spp", "1"),
        "'ball'",
        "another spec",
    )


def test_server_bad_store_scenes_and_port(server: Command, tmp_path: Path) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert_error_line(server("--store", str(afile), "--port", "0"), "--store", str(afile))
    assert_error_line(
        server("--store", str(tmp_path / "s"), "--port", "0", "--scenes", str(tmp_path / "missing")), "--scenes"
    )
    assert_error_line(server("--store", str(tmp_path / "s"), "--port", "70000"), "--port")
    assert_error_line(server("--port", "0"), "--store")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = str(taken.getsockname()[1])
        assert_error_line(server("--store", str(tmp_path / "s"), "--port", port), f"127.0.0.1:{port}", "--port")


@pytest.mark.parametrize(
    ("option", "value", "culprit"),
    [
        ("--budget-mb", "inf", "--budget-mb = inf is not finite"),
        ("--budget-mb", "nan", "--budget-mb = nan is not finite"),
        ("--budget-mb", "1e30", "--budget-mb = 1e+30 is above 16777216.0"),
        ("--budget-mb", "0", "--budget-mb = 0.0 is not positive"),
        ("--max-spp", "100000", "--max-spp = 100000 is above 4096"),
        ("--log-level", "loud", "--log-level"),
    ],
)
def test_server_refuses_non_finite_and_huge_values(
    server: Command, tmp_path: Path, option: str, value: str, culprit: str
) -> None:
    store = tmp_path / "s"
    assert_error_line(server("--store", str(store), "--port", "0", option, value), culprit)
    assert not store.exists()


@pytest.mark.parametrize(("name", "value"), [("TOLERANCE_POSITION", "inf"), ("RESOLUTIONS", "[4]")])
def test_server_refuses_a_bad_environment_setting(
    server: Command, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str, value: str
) -> None:
    """A CLOUDBAKING_* setting the settings refuse (a non-finite tolerance, a resolution outside the one limit)
    is one line naming the variable."""
    monkeypatch.setenv(f"CLOUDBAKING_{name}", value)
    assert_error_line(server("--store", str(tmp_path / "s"), "--port", "0"), f"CLOUDBAKING_{name}")
