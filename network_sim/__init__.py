"""The simulated network (docs/architecture.md, Network simulator): a TCP proxy process that imposes delay,
jitter, bandwidth, queueing and loss between client and server, driven by a deterministic virtual-clock model
of the same link (:mod:`network_sim.link`), with named profiles (:mod:`network_sim.profiles`), shipped seeded
LTE traces, and a self-test (``network-sim selftest``). It imports nothing of the other project packages but a
few small ``gicore`` modules (the CLI error policy, results, timing, plotting).
"""

#: The commands of ``network-sim`` that are services: a stop ends them with exit 0 (the others are batch commands).
SERVICES = ("proxy", "server")


def main() -> None:
    """``network-sim``: :mod:`network_sim.cli` loaded as :func:`gicore.error_policy.launch` loads a command (a stop
    while its modules load ends a service quietly)."""
    from gicore.error_policy import launch

    launch("network_sim.cli", SERVICES)
