"""``network-sim`` fails cleanly on bad input (docs/architecture.md, Errors): exit 2, one ``error:`` line
naming the culprit, no traceback, nothing written. Uses the shared harness of ``tests/helpers/cli.py``: the option
checks run the command's ``main`` in this process, the errors met on the network (an unreachable upstream, a taken
port) a real process."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import fields
from pathlib import Path

import pytest

from gicore.error_policy import UserError
from gicore.options import option_name
from network_sim import profiles as profile_table
from network_sim.cli import ProxyOptions, link_config
from network_sim.link import LinkConfig
from tests.helpers.cli import assert_user_error, check_user_error, run_main


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
    os.mkfifo(root / "fifo")  # opened, it would block until its other end is opened: forever
    return root


CASES = [
    (["--delay-ms", "-5"], "--delay-ms = -5.0 is below 0"),
    (["--delay-ms", "nan"], "--delay-ms = nan is not finite"),
    (["--delay-ms", "60001"], "--delay-ms = 60001.0 is above 60000"),
    (["--loss", "1.5"], "--loss = 1.5 is above 1.0"),
    (["--loss", "-0.1"], "--loss = -0.1 is below 0"),
    (["--jitter-ms", "-1"], "--jitter-ms = -1.0 is below 0"),
    (["--jitter-ms", "1e6"], "--jitter-ms = 1000000.0 is above 60000"),
    (["--jitter-dist", "cauchy"], "'--jitter-dist'"),
    (["--rate-mbit", "inf"], "--rate-mbit = inf is not finite"),
    (["--rate-mbit", "100001"], "--rate-mbit = 100001.0 is above 100000"),
    (["--rate-up-mbit", "-1"], "--rate-up-mbit = -1.0 is below 0"),
    (["--rate-down-mbit", "nan"], "--rate-down-mbit = nan is not finite"),
    (["--queue-bytes", "10"], "--queue-bytes = 10 is below 1500"),
    (["--queue-bytes", str(2**30 + 1)], f"--queue-bytes = {2**30 + 1} is above {2**30}"),
    (["--window-bytes", "1000"], "--window-bytes = 1000 is below 1500"),
    (["--window-bytes", str(2**40)], f"--window-bytes = {2**40} is above {2**30}"),
    (["--seed", "-1"], "--seed = -1 is below 0"),
    (["--seed", str(2**32)], f"--seed = {2**32} is above {2**32 - 1}"),
    (["--profile", "5g"], "--profile '5g' is not a known profile"),
    (["--trace-up", "bad.txt"], "trace bad.txt line 3: '2x0' is not a whole number"),
    (["--trace-down", "down.txt"], "trace down.txt line 2: timestamp 5 is smaller"),
    (["--trace-down", "missing.txt"], "trace missing.txt cannot be read"),
    (["--trace-up", "ok.txt", "--rate-up-mbit", "5"], "--trace-up and a rate for the up direction"),
    (["--listen", "localhost"], "--listen 'localhost' is not HOST:PORT"),
    (["--listen", "127.0.0.1:65536"], "--listen '127.0.0.1:65536' is not HOST:PORT"),
    (["--upstream", "127.0.0.1"], "--upstream '127.0.0.1' is not HOST:PORT"),  # the last --upstream counts
    (["--log", "afile/chunks.csv"], "--log folder afile is a file"),
    (["--log", "fifo"], "--log fifo is a FIFO, not a regular file"),
    (["--log", "."], "--log . is a directory, not a regular file"),
    (["--lateness", "fifo"], "--lateness fifo is a FIFO, not a regular file"),
    (["--lateness", "/dev/null"], "--lateness /dev/null is a character device, not a regular file"),
    (["--lateness", "afile/late.json"], "--lateness folder afile is a file"),
    (["--trace-up", "fifo"], "--trace-up fifo is a FIFO, not a regular file"),
    (["--trace-down", "fifo"], "--trace-down fifo is a FIFO, not a regular file"),
    (["--idle-min-bytes", "0"], "--idle-min-bytes = 0 is below 1"),
    (["--max-connections", "0"], "--max-connections = 0 is below 1"),
    (["--max-connections", str(10**7)], "--max-connections = 10000000 is above 1000000"),
]


@pytest.mark.parametrize(("args", "culprit"), CASES, ids=[c[1][:30] for c in CASES])
def test_bad_proxy_flags(
    workspace: Path, listener: int, args: list[str], culprit: str, monkeypatch: pytest.MonkeyPatch, capfd
) -> None:
    argv = ["network-sim", "proxy", "--upstream", f"127.0.0.1:{listener}", *args]
    check_user_error(run_main(argv, workspace, monkeypatch, capfd), culprit)


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


@pytest.mark.parametrize(
    ("argv", "culprit"),
    [
        (["proxy"], "Missing option '--upstream'"),
        (["selftest", "--out", "afile"], "--out afile is a file"),
        (["selftest", "--out", "new", "--seed", "-1"], "--seed = -1 is below 0"),
        (["server", "--listen", "nowhere"], "--listen 'nowhere' is not HOST:PORT"),
        (["server", "--listen", "h:99999"], "--listen 'h:99999' is not HOST:PORT"),
        (["traces", "--out", "afile"], "--out afile is a file"),
    ],
)
def test_other_commands(workspace: Path, argv: list[str], culprit: str, monkeypatch: pytest.MonkeyPatch, capfd) -> None:
    check_user_error(run_main(["network-sim", *argv], workspace, monkeypatch, capfd), culprit)


def test_options_map_onto_the_link_in_one_place() -> None:
    """Shared options set both directions over the profile's; a per-direction rate wins over --rate-mbit."""
    wan = profile_table.get("wan")
    link = link_config("wan", delay_ms=20.0, rate_mbit=3.0, rate_down_mbit=7.0, seed=5)
    assert (link.up.delay_ms, link.down.delay_ms, link.up.rate_mbit, link.down.rate_mbit) == (20.0, 20.0, 3.0, 7.0)
    assert link.up.queue_bytes == wan.up.queue_bytes and link.down.loss == wan.down.loss and link.seed == 5
    assert link_config() == LinkConfig()  # no profile, no option: an unshaped link
    assert link_config(rate_mbit=0.0).up.rate_mbit == 0.0  # a dead link stays possible
    with pytest.raises(UserError, match="--window-bytes = 1073741825 is above"):
        ProxyOptions(window_bytes=2**30 + 1)  # code building the options meets the command line's limits


def test_every_proxy_field_is_an_option_with_its_limits() -> None:
    from typer.main import get_command

    from network_sim.cli import app

    proxy = get_command(app).commands["proxy"]  # type: ignore[attr-defined]
    options = {opt for p in proxy.params for opt in p.opts}
    assert {option_name(f) for f in fields(ProxyOptions)} <= options
    assert next(p for p in proxy.params if p.name == "upstream").required


def test_profiles_lists_every_profile_with_its_source() -> None:
    exe = Path(sys.executable).parent / "network-sim"
    out = subprocess.run([str(exe), "profiles"], capture_output=True, text=True, timeout=60, check=True).stdout
    for name in ("loopback", "lan", "wifi", "wan", "lte", "3g", "rtt60", "rtt250"):
        assert f"\n{name}\n" in f"\n{out}"
    assert out.count("source:") >= 11 and "GamingAnywhere" in out and "mobileRegular3G" in out and "Outatime" in out
