"""The core plan of a measured run's processes (gicore.cores)."""

from __future__ import annotations

import pytest

from gicore import cores
from gicore.cores import pinning, taskset


def test_pinning_plan(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cores.shutil, "which", lambda name: "/usr/bin/taskset")
    monkeypatch.setattr(cores.os, "sched_getaffinity", lambda pid: {0, 1})
    assert pinning(True) == {"method": "taskset -c", "cores": [0, 1], "server": [0], "proxy": [0], "client": [1]}
    assert taskset(pinning(True), "client") == ["taskset", "-c", "1"]
    monkeypatch.setattr(cores.os, "sched_getaffinity", lambda pid: set(range(8)))
    plan = pinning(True)
    assert (plan["proxy"], plan["server"], plan["client"]) == ([0], [1, 2, 3], [4, 5, 6, 7])
    assert pinning(False)["method"] == "none" and taskset(pinning(False), "server") == []
    monkeypatch.setattr(cores.shutil, "which", lambda name: None)
    assert pinning(True) == {
        "method": "none",
        "reason": "taskset (util-linux) is not installed",
        "cores": list(range(8)),
    }
