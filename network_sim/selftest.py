"""``network-sim selftest``: does the proxy deliver what it is configured to?

Real processes: the endpoint server (:mod:`network_sim.endpoint`), a proxy process per setting in front of
it, and blocking clients here. All three share CLOCK_MONOTONIC, so one-way delays are measured directly.
For each setting it compares configured with realised values and checks the issue's targets:

- one-way delay, per direction, median within max(1 ms, 3 %) of the configured delay (5 to 300 ms);
- jitter: standard deviation of the one-way delay (both directions pooled) within 15 % of the configured one;
- goodput of a bulk transfer (at least 2 MB or 5 s) within 5 % of the configured rate (1 to 100 Mbit/s),
  and within 5 % of a trace's capacity over the same window; two concurrent downloads share the rate
  (their sum within 5 % of it: the rate belongs to the link, not to each connection);
- jitter on a dense stream (a rate-limited download): its mean delay and spread as configured;
- loss: the share of delayed probes consistent with the loss probability (99 % binomial interval), and
  the delay they pay equal to the retransmission timeout within max(1 ms, 3 %);
- the proxy's own overhead unshaped: added round-trip time p50 <= 0.3 ms, bulk >= 1 Gbit/s on loopback;
- every transfer byte-exact (SHA-256 of the received stream).

It also checks, from each proxy's lateness summary (``--lateness``), that every proxy wrote its chunks on time:
p99 of write time minus model release within max(0.1 RTT, 1 ms); a run that misses it was measured on a machine
too busy for its numbers. Results: ``network_selftest.csv`` (tidy, via :class:`gicore.results.Results`), its
provenance JSON, ``network_selftest.png``; the exit status says whether every target was met.
"""

from __future__ import annotations

import sys
from dataclasses import asdict
from pathlib import Path

from gicore.results import Results
from network_sim.process import network_sim
from network_sim.selftest_checks import Check, Measurements, SelftestConfig

BENCH = "network_selftest"


def _plot(checks: list[Check], png: Path) -> None:
    """Realised minus configured for delay, goodput and jitter, each against its target band."""
    from gicore.plotting import plt, save, ticker

    def error(c: Check, relative: bool) -> float:
        assert c.configured is not None
        return 100.0 * (c.measured / c.configured - 1.0) if relative else c.measured - c.configured

    panels = (
        (
            "one-way delay: median - configured (ms)",
            [("one_way_delay", "median")],
            False,
            lambda x: max(1.0, 0.03 * x),
            "configured delay (ms)",
        ),
        (
            "goodput: realised / configured - 1 (%)",
            [("goodput", "value"), ("trace_goodput", "value"), ("goodput_sum", "value")],
            True,
            lambda x: 5.0,
            "configured rate or trace capacity (Mbit/s)",
        ),
        (
            "jitter std: realised / configured - 1 (%)",
            [("jitter_std", "std")],
            True,
            lambda x: 15.0,
            "configured jitter std (ms)",
        ),
    )
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for (title, kinds, relative, band, xlabel), ax in zip(panels, axes):
        rows = [c for c in checks if (c.metric, c.stat) in kinds and c.configured]
        for direction, marker in (("up", "o"), ("down", "s"), ("both", "D")):
            sel = [c for c in rows if c.config.get("direction") == direction]
            if sel:
                ax.scatter(
                    [c.configured for c in sel],
                    [error(c, relative) for c in sel],
                    marker=marker,
                    label=direction,
                    alpha=0.8,
                )
        if rows:
            xs = sorted({c.configured for c in rows if c.configured})
            xs = [xs[0] * 0.8, *xs, xs[-1] * 1.25]
            ax.fill_between(
                xs, [-band(x) for x in xs], [band(x) for x in xs], color="tab:green", alpha=0.12, label="target"
            )
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(xlabel)
        ax.legend(fontsize=8)
    save(fig, png)


def run_selftest(config: SelftestConfig, out: Path, seed: int = 0) -> int:
    """Run every measurement, write CSV + provenance + plot into ``out``; returns the number of missed targets."""
    results = Results(BENCH, out, seed=seed, settings=asdict(config))
    workdir = out / "proxy_logs"
    workdir.mkdir(parents=True, exist_ok=True)
    with network_sim("server") as server:
        run = Measurements(config, server, seed, workdir)
        print(f"  {'check':<44} {'configured':>10} {'measured':>11} {'unit':<7} {'target':<26}", flush=True)
        for step in (
            run.overhead,
            run.delays,
            run.jitter,
            run.bulk_jitter,
            run.goodput,
            run.shared_rate,
            run.loss,
            run.trace,
        ):
            step(workdir)
        run.summary()
    for c in run.checks:
        common = dict(system="network_sim", scene=c.scene, metric=c.metric, unit=c.unit, **c.config)
        results.add(stat=c.stat, value=c.measured, **common)
        if c.configured is not None:
            results.add(stat="configured", value=c.configured, **common)
        if c.ok is not None:
            results.add(
                stat="target_met",
                value=float(c.ok),
                **{**common, "unit": "bool"},
                target=c.target,
                measured_stat=c.stat,
            )
    results.write()
    _plot(run.checks, out / f"{BENCH}.png")
    missed = sum(c.ok is False for c in run.checks)
    print(
        f"{len(run.checks)} checks, {missed} missed; results in {results.csv_path}",
        file=sys.stderr if missed else sys.stdout,
        flush=True,
    )
    return missed
