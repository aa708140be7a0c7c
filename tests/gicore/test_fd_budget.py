"""The connection budget of a process: its soft file-descriptor limit raised to the hard one, then the connections
that fit beside a reserve, each taking one or more descriptors; a lowered cap is said once, on stderr."""

from __future__ import annotations

import resource

import pytest

from gicore import fd_budget
from gicore.fd_budget import UNLIMITED_TARGET, connection_budget


def limits(monkeypatch: pytest.MonkeyPatch, soft: int, hard: int, refuse: bool = False) -> list[tuple[int, int]]:
    """Stand in for the process's RLIMIT_NOFILE: (soft, hard); the soft limits it is set to are recorded (a
    refused one raises, as Linux refuses what is over its own ceiling)."""
    asked: list[tuple[int, int]] = []
    state = {"soft": soft}

    def setrlimit(which: int, value: tuple[int, int]) -> None:
        asked.append(value)
        if refuse:
            raise ValueError("not allowed")
        state["soft"] = value[0]

    monkeypatch.setattr(fd_budget.resource, "getrlimit", lambda which: (state["soft"], hard))
    monkeypatch.setattr(fd_budget.resource, "setrlimit", setrlimit)
    return asked


def test_the_soft_limit_is_raised_to_the_hard_one_first(monkeypatch: pytest.MonkeyPatch) -> None:
    asked = limits(monkeypatch, 1024, 65536)
    assert connection_budget(10_000, 256) == (10_000, 65536) and asked == [(65536, 65536)]


def test_what_does_not_fit_is_lowered_and_said(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    limits(monkeypatch, 300, 300)
    assert connection_budget(1024, 256, who="a server: max_connections") == (44, 300)
    assert connection_budget(1024, 64, fds_each=2) == (118, 300)  # two sockets a connection; not said
    assert capsys.readouterr().err.splitlines() == [
        "a server: max_connections lowered to 44 to fit the file-descriptor limit 300 (raise it with ulimit -n)"
    ]
    assert connection_budget(1024, 400) == (1, 300)  # at least one, however little is left


def test_an_unlimited_hard_limit_asks_for_a_large_soft_one(monkeypatch: pytest.MonkeyPatch) -> None:
    asked = limits(monkeypatch, 1024, resource.RLIM_INFINITY)
    assert connection_budget(10**7, 256) == (UNLIMITED_TARGET - 256, UNLIMITED_TARGET)
    assert asked == [(UNLIMITED_TARGET, resource.RLIM_INFINITY)]
    limits(monkeypatch, 1024, resource.RLIM_INFINITY, refuse=True)
    assert connection_budget(10**7, 256) == (768, 1024)  # refused: the soft limit it has
    limits(monkeypatch, resource.RLIM_INFINITY, resource.RLIM_INFINITY)
    assert connection_budget(10**7, 256) == (10**7, resource.RLIM_INFINITY)  # no limit: all of them
