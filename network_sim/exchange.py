"""One request and its response on a modelled link: what a remote service's answer costs on any link, from
what was measured once (the benches sweep links with it instead of running a proxy per link).

The times come from :mod:`network_sim.link`'s virtual-clock model, the same code the proxy schedules with.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gicore.intervals import LEVEL, MIN_SAMPLES, RESAMPLES, Interval, Seed, quantiles, resampled, values_of
from network_sim.link import DOWN, UP, DirectionConfig, Link, LinkConfig


def sweep_link(rtt_ms: float, rate_mbit: float | None) -> LinkConfig:
    """A link with ``rtt_ms / 2`` one-way delay each way at ``rate_mbit`` (None: unlimited)."""
    direction = DirectionConfig(delay_ms=rtt_ms / 2, rate_mbit=rate_mbit)
    return LinkConfig(up=direction, down=direction)


@dataclass(frozen=True)
class CloudCost:
    """A cloud service's cost of one answer apart from the network (medians of the measured requests), and
    what it sends: enough to put its total on any link."""

    #: Median of total minus transmission: server, decode, warp, blend (ms).
    local_ms: float
    #: Median server time (ms): the response leaves the server this long after the request arrived.
    server_ms: float
    bytes_up: int
    bytes_down: int

    @classmethod
    def of(cls, samples: dict[str, list[float]]) -> CloudCost:
        """The medians of measured requests: ``total``, ``transmission``, ``server`` (ms), ``bytes_up``,
        ``bytes_down`` per request."""
        rest = np.subtract(samples["total"], samples["transmission"])
        return cls(
            float(np.median(rest)),
            float(np.median(samples["server"])),
            int(np.median(samples["bytes_up"])),
            int(np.median(samples["bytes_down"])),
        )

    def network_ms(self, link: LinkConfig, starts: int = 1) -> float:
        """Request upload plus response download on ``link`` (median over ``starts`` start times 0.5 s apart,
        which matters for traces and jitter)."""
        times = []
        for i in range(starts):
            model, t0 = Link(link), 0.5 * i
            arrived = model.message(0, UP, self.bytes_up, t0)
            done = model.message(0, DOWN, self.bytes_down, arrived + self.server_ms / 1e3)
            times.append((done - t0) * 1e3 - self.server_ms)
        return float(np.median(times))

    def total_ms(self, link: LinkConfig, starts: int = 1) -> float:
        return self.local_ms + self.network_ms(link, starts)

    def crossover_rtt_ms(self, local_total_ms: float, rate_mbit: float | None) -> float:
        """The RTT beyond which a local alternative taking ``local_total_ms`` beats this cost on a ``rate_mbit``
        link (0: at any RTT; inf: at none up to a minute)."""

        def gap(rtt: float) -> float:
            return self.total_ms(sweep_link(rtt, rate_mbit)) - local_total_ms

        if gap(0.0) >= 0:
            return 0.0
        low, high = 0.0, 100.0
        while gap(high) < 0:
            low, high = high, 2 * high
            if high > 60_000.0:
                return math.inf
        while high - low > 0.05:
            mid = 0.5 * (low + high)
            low, high = (mid, high) if gap(mid) < 0 else (low, mid)
        return 0.5 * (low + high)


#: What the link model reads of a cloud request (:meth:`CloudCost.of`), resampled together.
COST_STAGES = ("total", "transmission", "server", "bytes_up", "bytes_down")


def crossover_interval(
    stages: dict[str, Sequence[float]],
    local_totals: Sequence[float],
    rate_mbit: float | None,
    seed: Seed,
    level: float = LEVEL,
    resamples: int = RESAMPLES,
) -> Interval | None:
    """The interval of :meth:`CloudCost.crossover_rtt_ms` of the cloud requests' ``stages`` against the median
    of ``local_totals`` (GIGAN's per-map totals): each resample draws the requests (their stages together) and the
    local maps apart. A resample's medians are order statistics of the samples, so resamples repeat the same
    cost and local median: each distinct pair is solved once (2000 resamples of 40 requests took a second on a
    2-core Xeon)."""
    cloud = {name: values_of(stages[name]) for name in COST_STAGES}
    local = values_of(local_totals)
    n = cloud["total"].size
    if min(n, local.size) < MIN_SAMPLES:
        return None
    rng = np.random.default_rng(seed)
    local_medians = resampled(local, rng, resamples, np.median)
    solved: dict[tuple[CloudCost, float], float] = {}
    crossovers = np.empty(resamples)
    for i, local_ms in enumerate(local_medians):
        picked = rng.integers(0, n, n)
        cost = CloudCost.of({name: values[picked] for name, values in cloud.items()})
        key = (cost, float(local_ms))
        if key not in solved:
            solved[key] = cost.crossover_rtt_ms(key[1], rate_mbit)
        crossovers[i] = solved[key]
    return quantiles(crossovers, level, resamples)
