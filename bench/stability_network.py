"""`bench stability`'s network cases that need two packages at once: the cloud client
(:mod:`baseline_cloudbaking`) asking a real server through real proxies (:mod:`network_sim`) on a LAN profile
and on each of :data:`network_sim.stability_cases.DEAD_LINKS`, which the client's timeouts must end."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import replace

from baseline_cloudbaking.stability_cases import Served
from gicore.stability import Case, Outcome, Rejected, Scene
from network_sim.stability_cases import DEAD_LINKS


def through_proxy(
    s: Scene, served: Served, stack: ExitStack, flags: list[str], timeout: float
) -> Callable[[], Outcome]:
    """A case's run: the cloud client asks for the GI camera's map through a real proxy with ``flags``."""
    from baseline_cloudbaking.client import RemoteSource
    from network_sim.process import proxy
    from web3d.children import url

    def run() -> Outcome:
        host, _, port = served.remote.server.removeprefix("http://").rpartition(":")
        running = stack.enter_context(proxy((host, int(port)), *flags, timeout=30.0))
        remote = replace(served.remote, server=url(running), connect_timeout_s=timeout, read_timeout_s=timeout,
                         deadline_s=2 * timeout, retry_after_s=0.0)  # fmt: skip
        with RemoteSource(remote) as source:
            source.request(s.gi_camera, s.light, 0)
            if not source.wait(4 * timeout + 5.0):
                raise RuntimeError(
                    f"the client's request is still in flight {4 * timeout + 5:g} s later despite its timeouts"
                )
            record = source.records[-1]
            gi = source.latest()
        if record["status"] != "ok":
            raise Rejected(
                f"client gave up after {float(record['latency_ms']) / 1e3:.2f} s: {record['status']}: {record['error']}"
            )
        return Outcome((gi.radiance, gi.depth), note=f"map in {float(record['latency_ms']):.0f} ms")

    return run


def network_cases(s: Scene, served: Served, stack: ExitStack) -> list[Case]:
    """The cloud client through real proxies: a LAN profile (the control asks for the map the server case "valid
    request" baked: a hit, with room for a miss's render), then each dead link, which its timeouts must end."""
    control = through_proxy(s, served, stack, ["--profile", "lan"], served.case_timeout_s / 3)
    cases = [Case("network", "proxy + client: LAN profile (control)", "finite", control)]
    for name, settings in DEAD_LINKS.items():
        flag, value = next(iter(settings.items()))
        run = through_proxy(s, served, stack, [f"--{flag.replace('_', '-')}", f"{value:g}"], served.client_timeout_s)
        cases.append(Case("network", f"proxy + client: {name}", "rejected", run))
    return cases
