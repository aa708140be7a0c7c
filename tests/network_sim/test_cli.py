"""``network-sim`` fails cleanly on bad input (SPEC §8a): exit 2, one ``error:`` line naming the culprit,
no traceback, nothing written. Uses the shared harness of ``tests/helpers/cli.py``."""

from __future__ import annotations

import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers.cli import assert_user_error


@pytest.fixture(scope="module")
def listener() -> Iterator[int]:
    """A port something listens on (an upstream that accepts, and a port that is taken)."""
    with socket.create_server(("127.0.0.1", 0)) as sock:
        yield sock.getsockname()[1]


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("netcli")
    (root / "bad.txt").write_text("10\n20\n2x0\n30\n")
    (root / "down.txt").write_text("10\n5\n")
    (root / "ok.txt").write_text("1\n")
    (root / "afile").write_text("not a folder")
    return root


CASES = [
    (["--delay-ms", "-5"], "'--delay-ms'"),
    (["--delay-ms", "nan"], "'--delay-ms'"),
    (["--loss", "1.5"], "'--loss'"),
    (["--jitter-ms", "-1"], "'--jitter-ms'"),
    (["--jitter-dist", "cauchy"], "'--jitter-dist'"),
    (["--rate-mbit", "inf"], "--rate-mbit inf is not a finite number"),
    (["--queue-bytes", "10"], "'--queue-bytes'"),
    (["--profile", "5g"], "--profile '5g' is not a known profile"),
    (["--trace-up", "bad.txt"], "trace bad.txt line 3: '2x0' is not a whole number"),
    (["--trace-down", "down.txt"], "trace down.txt line 2: timestamp 5 is smaller"),
    (["--trace-down", "missing.txt"], "trace missing.txt cannot be read"),
    (["--trace-up", "ok.txt", "--rate-up-mbit", "5"], "--trace-up and a rate for the up direction"),
    (["--listen", "localhost"], "--listen 'localhost' is not HOST:PORT"),
]


@pytest.mark.parametrize(("args", "culprit"), CASES, ids=[c[1][:30] for c in CASES])
def test_bad_proxy_flags(workspace: Path, listener: int, args: list[str], culprit: str) -> None:
    assert_user_error(["network-sim", "proxy", "--upstream", f"127.0.0.1:{listener}", *args], culprit, workspace)


def test_unreachable_upstream(workspace: Path) -> None:
    with socket.create_server(("127.0.0.1", 0)) as sock:
        port = sock.getsockname()[1]  # free once closed: nothing listens there
    assert_user_error(
        ["network-sim", "proxy", "--upstream", f"127.0.0.1:{port}"],
        f"--upstream 127.0.0.1:{port} is unreachable",
        workspace,
    )


def test_listen_port_taken(workspace: Path, listener: int) -> None:
    argv = ["network-sim", "proxy", "--upstream", f"127.0.0.1:{listener}", "--listen", f"127.0.0.1:{listener}"]
    assert_user_error(argv, f"--listen 127.0.0.1:{listener}: cannot listen", workspace)


def test_other_commands(workspace: Path) -> None:
    assert_user_error(["network-sim", "selftest", "--out", "afile"], "--out afile is a file", workspace)
    assert_user_error(
        ["network-sim", "server", "--listen", "nowhere"], "--listen 'nowhere' is not HOST:PORT", workspace
    )
    assert_user_error(["network-sim", "traces", "--out", "afile"], "--out afile is a file", workspace)


def test_profiles_lists_every_profile_with_its_source() -> None:
    exe = Path(sys.executable).parent / "network-sim"
    out = subprocess.run([str(exe), "profiles"], capture_output=True, text=True, timeout=60, check=True).stdout
    for name in ("loopback", "lan", "wifi", "wan", "lte", "3g", "rtt60", "rtt250"):
        assert f"\n{name}\n" in f"\n{out}"
    assert out.count("source:") >= 11 and "GamingAnywhere" in out and "mobileRegular3G" in out and "Outatime" in out
