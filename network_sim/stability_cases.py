"""The extreme links the network simulator's link model must survive, as :class:`gicore.stability.Case` lists:
zero bandwidth, total loss and the proxy's longest delay (:data:`DEAD_LINKS`, which ``bench stability`` also
puts between the cloud client and a real server); ``bench stability`` judges them."""

from __future__ import annotations

import math
from collections.abc import Callable

from gicore.stability import Case, Expect, Outcome, Rejected
from network_sim.cli import DELAY_MS_MAX

#: The dead and stiff links of the network cases: name -> one direction's settings (both directions alike).
DEAD_LINKS = {
    "zero bandwidth": {"rate_mbit": 0.0},
    "100 % loss": {"loss": 1.0},
    f"{DELAY_MS_MAX / 1e3:g} s one-way delay (the proxy's bound)": {"delay_ms": DELAY_MS_MAX},
}


def link_model_cases() -> list[Case]:
    from network_sim.link import DOWN, UP, DirectionConfig, Link, LinkConfig

    request, response = 600, 40_000

    def exchange(settings: dict[str, float]) -> Callable[[], Outcome]:
        def run() -> Outcome:
            direction = DirectionConfig(**settings)
            link = Link(LinkConfig(up=direction, down=direction))
            arrived = link.message(0, UP, request, 0.0)
            done = link.message(0, DOWN, response, arrived) if math.isfinite(arrived) else math.inf
            if not math.isfinite(done):
                raise Rejected(
                    "the model never delivers the request/response (release time inf): a client sees its timeout"
                )
            expected = 2 * direction.delay_ms / 1e3
            return Outcome(
                (done,),
                abs(done - expected) / expected,
                "relative error vs 2 × one-way delay",
                1e-9,
                f"response after {done:.6g} s",
            )

        return run

    expect: dict[str, Expect] = {name: "finite" if "delay" in name else "rejected" for name in DEAD_LINKS}
    return [
        Case("network", f"link model: {name}", expect[name], exchange(settings))
        for name, settings in DEAD_LINKS.items()
    ]
