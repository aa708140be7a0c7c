"""The simulated network (docs/architecture.md, Network simulator): a TCP proxy process that imposes delay,
jitter, bandwidth, queueing and loss between client and server, driven by a deterministic virtual-clock model
of the same link (:mod:`network_sim.link`), with named profiles (:mod:`network_sim.profiles`), shipped seeded
LTE traces, and a self-test (``network-sim selftest``). It imports nothing of the other project packages but a
few small ``gicore`` modules (the CLI error policy, results, timing, plotting).
"""
