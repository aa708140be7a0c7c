"""Which cores each process of a measured run may use: a cloud-baking server, its network proxy and the clients
pinned apart (``taskset -c``), so that one role's load does not land in another's timings."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


def pinning(enabled: bool) -> dict[str, Any]:
    """Cores of the server, the proxy and the clients (``taskset -c``): with 2 cores the server and the
    proxy share one and the clients get the other; with more the proxy gets one, the server about half
    of the rest and the clients the others. ``method`` is ``none`` (with the reason) when not pinned."""
    cores = sorted(os.sched_getaffinity(0))
    if not enabled:
        return {"method": "none", "reason": "--no-pin", "cores": cores}
    if shutil.which("taskset") is None:
        return {"method": "none", "reason": "taskset (util-linux) is not installed", "cores": cores}
    if len(cores) < 2:
        return {"method": "none", "reason": "one core: every process shares it", "cores": cores}
    if len(cores) == 2:
        roles = {"server": cores[:1], "proxy": cores[:1], "client": cores[1:]}
    else:
        split = 1 + (len(cores) - 1) // 2
        roles = {"proxy": cores[:1], "server": cores[1:split], "client": cores[split:]}
    return {"method": "taskset -c", "cores": cores} | roles


@contextmanager
def client_cores(plan: dict[str, Any]) -> Iterator[None]:
    """Run this thread (and the threads it starts) on the plan's client cores, then restore."""
    if plan["method"] == "none":
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, plan["client"])
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def taskset(plan: dict[str, Any], role: str) -> list[str]:
    """The command prefix that pins a process of ``role`` as ``plan`` says (empty when not pinned)."""
    return ["taskset", "-c", ",".join(map(str, plan[role]))] if plan["method"] != "none" else []


def threads(plan: dict[str, Any], role: str) -> int:
    """The cores a process of ``role`` may use."""
    return len(plan[role]) if plan["method"] != "none" else len(plan["cores"])
