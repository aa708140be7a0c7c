"""How many connections a process can hold open: its file-descriptor limit, raised first, less what it keeps for
everything else. ``cloudbaking-server`` and ``network-sim proxy`` fit their connection caps to it, and the server's
load test its idle connections."""

from __future__ import annotations

import resource
import sys

#: The soft limit asked for where the hard one is unlimited (Linux refuses an unlimited soft limit).
UNLIMITED_TARGET = 1 << 20


def connection_budget(wanted: int, reserve: int, fds_each: int = 1, who: str | None = None) -> tuple[int, int]:
    """``wanted`` connections lowered to what the file-descriptor limit holds, each connection taking ``fds_each``
    descriptors beside the ``reserve`` kept for everything else, at least one; and that limit. The soft limit is
    raised to the hard one first. ``who`` (e.g. ``cloudbaking-server: max_connections``): say on stderr, naming
    it, when the cap is lowered."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and (hard == resource.RLIM_INFINITY or soft < hard):
        target = hard if hard != resource.RLIM_INFINITY else max(soft, UNLIMITED_TARGET)
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        except (ValueError, OSError):
            pass
    if soft == resource.RLIM_INFINITY:
        return wanted, soft
    budget = max(1, min(wanted, (soft - reserve) // fds_each))
    if budget < wanted and who is not None:
        print(f"{who} lowered to {budget} to fit the file-descriptor limit {soft} (raise it with ulimit -n)",
              file=sys.stderr, flush=True)  # fmt: skip
    return budget, soft
