"""What ``network-sim selftest`` (:mod:`network_sim.selftest`) measures: its settings, and each measurement
against the proxy process in front of the endpoint server, compared with what the proxy was configured to
deliver (:class:`Check`).
"""

from __future__ import annotations

import csv
import itertools
import math
import statistics
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from network_sim import endpoint
from network_sim.chunklog import lateness_limit_ms, read_lateness
from network_sim.link import MIN_RTO_S
from network_sim.process import Running, network_sim
from network_sim.profiles import get as get_profile

_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class SelftestConfig:
    """What the self-test runs; the defaults are the full run, :meth:`quick` the short one."""

    #: Seconds of probes per delay setting, and the mean gap between probes.
    probe_s: float = 5.0
    probe_interval_s: float = 0.005
    #: One-way delays checked, ms (no jitter, unlimited rate).
    delays_ms: tuple[float, ...] = (5.0, 50.0, 300.0)
    #: Jitter settings: (one-way delay ms, jitter standard deviation ms, distribution), and seconds of probes each.
    jitters: tuple[tuple[float, float, str], ...] = (
        (30.0, 3.0, "normal"),
        (30.0, 3.0, "uniform"),
        (30.0, 3.0, "pareto"),
        (100.0, 10.0, "normal"),
    )
    jitter_s: float = 15.0
    #: Rates checked, Mbit/s; a bulk transfer carries at least ``bulk_bytes`` and lasts at least ``bulk_s``
    #: seconds, but never more than ``bulk_max_s`` (2 MB or 5 s, as the issue asks).
    rates_mbit: tuple[float, ...] = (1.0, 10.0, 100.0)
    bulk_bytes: int = 2_000_000
    bulk_s: float = 5.0
    bulk_max_s: float = 5.0
    #: Rate two concurrent downloads share (their bulk is split between them).
    shared_rate_mbit: float = 10.0
    #: Loss check: loss probability, one-way delay (ms), probes (each on its own connection).
    loss: float = 0.1
    loss_delay_ms: float = 20.0
    loss_probes: int = 400
    #: Trace check: profile, and seconds of capacity each bulk transfer asks for.
    trace_profile: str = "lte"
    trace_s: float = 10.0
    #: Overhead check: round trips per path, and bytes of the unshaped bulk transfer.
    pings: int = 5000
    overhead_bytes: int = 1 << 30

    @classmethod
    def quick(cls) -> SelftestConfig:
        """About a minute and a half on two cores."""
        return cls(
            probe_s=2.0,
            jitters=((30.0, 3.0, "normal"), (30.0, 3.0, "pareto")),
            jitter_s=10.0,
            bulk_s=2.0,
            loss_probes=150,
            trace_s=5.0,
            pings=2000,
            overhead_bytes=256 << 20,
        )

    def bulk_bytes_at(self, rate_mbit: float) -> int:
        bytes_per_s = rate_mbit * 1e6 / 8
        return int(bytes_per_s * min(max(self.bulk_bytes / bytes_per_s, self.bulk_s), self.bulk_max_s))


@dataclass
class Check:
    """One compared quantity: what was configured, what was measured, and whether the target holds."""

    name: str
    scene: str  # the setting (a CSV "scene")
    metric: str
    stat: str
    unit: str
    measured: float
    configured: float | None = None
    target: str = ""  # empty: reported, no target
    ok: bool | None = None
    config: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # A verdict computed with numpy is a numpy bool, which `is False` never matches: counted as a plain bool.
        if self.ok is not None:
            self.ok = bool(self.ok)


def _within(measured: float, configured: float, tolerance: float) -> bool:
    return math.isfinite(measured) and abs(measured - configured) <= tolerance


class Measurements:
    """One self-test run's measurements: the server, the checks so far, and helpers that start proxies."""

    def __init__(self, config: SelftestConfig, server: Running, seed: int, workdir: Path) -> None:
        self.config = config
        self.server = server
        self.seed = seed
        self.workdir = workdir
        self.checks: list[Check] = []
        self.transfers: list[bool] = []
        #: Each proxy run's lateness summary (``network-sim proxy --lateness``).
        self.lateness: list[dict[str, Any]] = []
        self._runs = itertools.count()

    @contextmanager
    def proxy(self, *args: str, log: Path | None = None) -> Iterator[tuple[tuple[str, int], float]]:
        """A proxy in front of the server; yields its address and its clock origin (CLOCK_MONOTONIC s); its
        lateness summary is kept once it stopped."""
        host, port = self.server.addr
        summary = self.workdir / f"lateness{next(self._runs)}.json"
        extra = ["--lateness", str(summary), *(["--log", str(log)] if log is not None else [])]
        with network_sim("proxy", "--upstream", f"{host}:{port}", "--seed", str(self.seed), *args, *extra) as running:
            origin = float(running.readline(10.0).split()[2])
            yield running.addr, origin
        self.lateness.append(read_lateness(summary))

    def add(self, check: Check) -> None:
        self.checks.append(check)
        mark = {True: "ok", False: "MISSED", None: ""}[check.ok]
        configured = "" if check.configured is None else f"{check.configured:.4g}"
        print(
            f"  {check.name:<44} {configured:>10} {check.measured:>11.4g} {check.unit:<7} {check.target:<26} {mark}",
            flush=True,
        )

    def transfer(self, result: endpoint.Transfer) -> endpoint.Transfer:
        self.transfers.append(result.intact)
        return result

    # -- the measurements -----------------------------------------------------------------------------
    def overhead(self, workdir: Path) -> None:
        c = self.config
        direct: list[float] = []
        proxied: list[float] = []
        with self.proxy("--profile", "loopback") as (addr, _):
            for _ in range(4):  # interleave blocks so load changes hit both paths alike
                direct += endpoint.round_trips(self.server.addr, c.pings // 4, _TIMEOUT_S)
                proxied += endpoint.round_trips(addr, c.pings // 4, _TIMEOUT_S)
            bulk = self.transfer(endpoint.upload(addr, c.overhead_bytes, self.seed, _TIMEOUT_S))
        reference = self.transfer(endpoint.upload(self.server.addr, c.overhead_bytes, self.seed, _TIMEOUT_S))
        for q, limit in ((50, 0.3), (99, None)):
            added = (np.percentile(proxied, q) - np.percentile(direct, q)) * 1e3
            self.add(
                Check(
                    f"added RTT p{q} (loopback proxy vs direct)",
                    "loopback",
                    "added_rtt",
                    f"p{q}",
                    "ms",
                    float(added),
                    0.0,
                    f"<= {limit} ms" if limit else "",
                    added <= limit if limit else None,
                    {"direct_ms": float(np.percentile(direct, q) * 1e3), "pings": len(direct)},
                )
            )
        self.add(
            Check(
                "bulk throughput through loopback proxy",
                "loopback",
                "bulk_throughput",
                "value",
                "Mbit/s",
                bulk.goodput_mbit,
                None,
                ">= 1000 Mbit/s",
                bulk.goodput_mbit >= 1000,
                {"bytes": c.overhead_bytes},
            )
        )
        self.add(
            Check(
                "bulk throughput direct (reference)",
                "direct",
                "bulk_throughput",
                "value",
                "Mbit/s",
                reference.goodput_mbit,
                config={"bytes": c.overhead_bytes},
            )
        )

    def delays(self, workdir: Path) -> None:
        c = self.config
        for delay in c.delays_ms:
            with self.proxy("--delay-ms", f"{delay:g}", log=workdir / f"delay{delay:g}.csv") as (addr, _):
                count = max(20, int(c.probe_s / c.probe_interval_s))
                results = endpoint.probes(addr, count, c.probe_interval_s, _TIMEOUT_S, self.seed)
            tolerance = max(1.0, 0.03 * delay)
            for direction, values in (
                ("up", [p.up_s * 1e3 for p in results]),
                ("down", [p.down_s * 1e3 for p in results]),
            ):
                median = statistics.median(values)
                config = {"delay_ms": delay, "direction": direction, "probes": len(values)}
                self.add(
                    Check(
                        f"one-way delay {delay:g} ms {direction}, median",
                        f"delay{delay:g}",
                        "one_way_delay",
                        "median",
                        "ms",
                        median,
                        delay,
                        f"|err| <= {tolerance:.3g} ms",
                        _within(median, delay, tolerance),
                        config,
                    )
                )
                self.add(
                    Check(
                        f"one-way delay {delay:g} ms {direction}, p95",
                        f"delay{delay:g}",
                        "one_way_delay",
                        "p95",
                        "ms",
                        float(np.percentile(values, 95)),
                        delay,
                        config=config,
                    )
                )

    def jitter(self, workdir: Path) -> None:
        """Both directions carry the same jitter, independently; the target is checked on their pooled
        delays (twice the samples: a window's std of a heavy-tailed process scatters widely, and the
        Pareto's 10 s pooled miss the 15 % band in under 1 % of seeds in the model, a single direction's 10 s
        in 6 %); each direction's std is reported too."""
        c = self.config
        for delay, jitter, dist in c.jitters:
            scene = f"jitter_{dist}{jitter:g}"
            args = ("--delay-ms", f"{delay:g}", "--jitter-ms", f"{jitter:g}", "--jitter-dist", dist)
            with self.proxy(*args, log=workdir / f"{scene}.csv") as (addr, _):
                results = endpoint.probes(
                    addr, int(c.jitter_s / c.probe_interval_s), c.probe_interval_s, _TIMEOUT_S, self.seed
                )
            config = {"delay_ms": delay, "jitter_ms": jitter, "dist": dist, "probes": len(results)}
            both = {"up": [p.up_s * 1e3 for p in results], "down": [p.down_s * 1e3 for p in results]}
            pooled = statistics.pstdev(both["up"] + both["down"])
            self.add(
                Check(
                    f"jitter std {dist} {jitter:g} ms (delay {delay:g}), both ways",
                    scene,
                    "jitter_std",
                    "std",
                    "ms",
                    pooled,
                    jitter,
                    "within 15 %",
                    _within(pooled, jitter, 0.15 * jitter),
                    config | {"direction": "both"},
                )
            )
            for direction, values in both.items():
                more = config | {"direction": direction}
                self.add(
                    Check(
                        f"  {direction}: std",
                        scene,
                        "jitter_std",
                        "std",
                        "ms",
                        statistics.pstdev(values),
                        jitter,
                        config=more,
                    )
                )
                self.add(
                    Check(
                        f"  {direction}: mean delay",
                        scene,
                        "one_way_delay",
                        "mean",
                        "ms",
                        statistics.fmean(values),
                        delay,
                        config=more,
                    )
                )

    def goodput(self, workdir: Path) -> None:
        c = self.config
        for rate in c.rates_mbit:
            nbytes = c.bulk_bytes_at(rate)
            with self.proxy("--rate-mbit", f"{rate:g}") as (addr, _):
                up = self.transfer(endpoint.upload(addr, nbytes, self.seed, _TIMEOUT_S))
                down = self.transfer(endpoint.download(addr, nbytes, self.seed, _TIMEOUT_S))
            for direction, result in (("up", up), ("down", down)):
                self.add(
                    Check(
                        f"goodput {rate:g} Mbit/s {direction}",
                        f"rate{rate:g}",
                        "goodput",
                        "value",
                        "Mbit/s",
                        result.goodput_mbit,
                        rate,
                        "within 5 %",
                        _within(result.goodput_mbit, rate, 0.05 * rate),
                        {
                            "rate_mbit": rate,
                            "direction": direction,
                            "bytes": nbytes,
                            "seconds": result.last_s - result.start_s,
                        },
                    )
                )

    def shared_rate(self, workdir: Path) -> None:
        """Connections of a direction share its rate, as on one bottleneck link: two concurrent downloads
        together get the configured rate (not twice it). The shared queue is FIFO in the order chunks are
        read and there is no congestion control, so the two are served in arrival order, not in fair shares."""
        c = self.config
        rate = c.shared_rate_mbit
        nbytes = c.bulk_bytes_at(rate) // 2
        with self.proxy("--rate-mbit", f"{rate:g}") as (addr, _):
            with ThreadPoolExecutor(2) as pool:
                pair = [
                    self.transfer(r)
                    for r in pool.map(lambda seed: endpoint.download(addr, nbytes, seed, _TIMEOUT_S), (1, 2))
                ]
        total = endpoint.link_goodput_mbit(pair)
        config = {"rate_mbit": rate, "direction": "down", "connections": 2, "bytes_each": nbytes}
        self.add(
            Check(
                f"shared rate: 2 downloads at {rate:g} Mbit/s, sum",
                "shared_rate",
                "goodput_sum",
                "value",
                "Mbit/s",
                total,
                rate,
                "within 5 %",
                _within(total, rate, 0.05 * rate),
                config,
            )
        )

    def bulk_jitter(self, workdir: Path) -> None:
        """Jitter on a dense stream (a rate-limited download, from the proxy log: write time minus the time the
        chunk left the bottleneck): the mean delay must not drift up and the spread must not collapse, as
        they do when per-chunk independent delays queue behind one another (Toxiproxy's latency toxic)."""
        c = self.config
        delay, jitter, rate = 30.0, 3.0, 10.0
        log = workdir / "bulk_jitter.csv"
        with self.proxy(
            "--delay-ms", f"{delay:g}", "--jitter-ms", f"{jitter:g}", "--rate-mbit", f"{rate:g}", log=log
        ) as (addr, _):
            self.transfer(endpoint.download(addr, c.bulk_bytes_at(rate), self.seed, _TIMEOUT_S))
        with log.open(newline="") as fh:
            delays = [
                (float(r["sent_s"]) - float(r["ready_s"])) * 1e3
                for r in csv.DictReader(fh)
                if r["direction"] == "down" and r["sent_s"]
            ]
        config = {"delay_ms": delay, "jitter_ms": jitter, "rate_mbit": rate, "direction": "down", "chunks": len(delays)}
        mean, std = statistics.fmean(delays), statistics.pstdev(delays)
        self.add(
            Check(
                "bulk stream: mean one-way delay",
                "bulk_jitter",
                "one_way_delay",
                "mean",
                "ms",
                mean,
                delay,
                f"|err| <= {max(1.0, 0.03 * delay):.3g} ms",
                _within(mean, delay, max(1.0, 0.03 * delay)),
                config,
            )
        )
        self.add(
            Check(
                "bulk stream: jitter std",
                "bulk_jitter",
                "jitter_std",
                "std",
                "ms",
                std,
                jitter,
                "within 15 %",
                _within(std, jitter, 0.15 * jitter),
                config,
            )
        )

    def loss(self, workdir: Path) -> None:
        c = self.config
        rto_ms = max(MIN_RTO_S, 4 * c.loss_delay_ms / 1e3) * 1e3  # max(200 ms, 2 RTT), RTT = 2 * one-way delay
        with self.proxy("--delay-ms", f"{c.loss_delay_ms:g}", "--loss", f"{c.loss:g}") as (addr, _):
            with ThreadPoolExecutor(8) as pool:
                ups = list(
                    pool.map(
                        lambda i: endpoint.probes(addr, 1, 1e-4, _TIMEOUT_S, i)[0].up_s * 1e3, range(c.loss_probes)
                    )
                )
        extra = [u - c.loss_delay_ms for u in ups]
        delayed = [e for e in extra if e > rto_ms / 2]
        share = len(delayed) / len(extra)
        half_width = 2.576 * math.sqrt(c.loss * (1 - c.loss) / len(extra))
        config = {"loss": c.loss, "delay_ms": c.loss_delay_ms, "probes": len(extra), "rto_ms": rto_ms}
        self.add(
            Check(
                f"share of probes delayed by loss (p = {c.loss:g})",
                "loss",
                "loss_share",
                "value",
                "ratio",
                share,
                c.loss,
                f"|err| <= {half_width:.3f} (99 %)",
                _within(share, c.loss, half_width),
                config,
            )
        )
        paid = statistics.median(delayed) if delayed else math.nan
        self.add(
            Check(
                "extra delay of a lost segment (RTO)",
                "loss",
                "loss_delay",
                "median",
                "ms",
                paid,
                rto_ms,
                f"|err| <= {max(1.0, 0.03 * rto_ms):.3g} ms",
                _within(paid, rto_ms, max(1.0, 0.03 * rto_ms)),
                config,
            )
        )

    def trace(self, workdir: Path) -> None:
        c = self.config
        profile = get_profile(c.trace_profile)
        with self.proxy("--profile", c.trace_profile) as (addr, origin):
            for direction, settings in (("down", profile.down), ("up", profile.up)):
                trace = settings.trace
                assert trace is not None
                nbytes = int(trace.mean_mbit * 1e6 / 8 * c.trace_s)
                move = endpoint.download if direction == "down" else endpoint.upload
                result = self.transfer(move(addr, nbytes, self.seed, _TIMEOUT_S))
                delay = settings.delay_ms / 1e3
                start, end = (
                    result.start_s - origin - delay,
                    result.last_s - origin - delay,
                )  # when the link delivered them
                capacity = trace.capacity_bytes(start, end) * 8 / (end - start) / 1e6
                config = {"profile": c.trace_profile, "direction": direction, "bytes": nbytes, "window_s": [start, end]}
                ok = _within(result.goodput_mbit, capacity, 0.05 * capacity)
                self.add(
                    Check(
                        f"trace goodput {c.trace_profile} {direction} (configured: capacity)",
                        c.trace_profile,
                        "trace_goodput",
                        "value",
                        "Mbit/s",
                        result.goodput_mbit,
                        capacity,
                        "within 5 %",
                        ok,
                        config,
                    )
                )

    def summary(self) -> None:
        intact = sum(self.transfers)
        self.add(
            Check(
                "byte-exact transfers (SHA-256)",
                "all",
                "intact_transfers",
                "value",
                "count",
                intact,
                len(self.transfers),
                "all",
                intact == len(self.transfers),
            )
        )
        self.lateness_summary()

    def lateness_summary(self) -> None:
        """Whether every proxy kept time (p99 lateness within max(0.1 RTT, 1 ms)): where one did not, the machine
        was too busy for the numbers it measured, whatever they are. And the worst run's p50 and p99."""
        on_time = sum(bool(r["reliable"]) for r in self.lateness)
        config = {"runs": len(self.lateness), "chunks": sum(r["all"]["chunks"] for r in self.lateness)}
        self.add(
            Check(
                "proxy runs on time (p99 lateness <= limit)",
                "all",
                "reliable_runs",
                "value",
                "count",
                on_time,
                len(self.lateness),
                "all (max(0.1 RTT, 1 ms))",
                on_time == len(self.lateness),
                config,
            )
        )
        for q in (50, 99):
            late = [(r["all"][f"p{q}_ms"], r["rtt_ms"]) for r in self.lateness if r["all"][f"p{q}_ms"] is not None]
            if late:
                worst, rtt = max(late)
                self.add(
                    Check(
                        f"proxy write lateness vs model release, p{q}",
                        "all",
                        "release_lateness",
                        f"p{q}",
                        "ms",
                        worst,
                        0.0,
                        config=config | {"run": "worst", "rtt_ms": rtt, "limit_ms": lateness_limit_ms(rtt)},
                    )
                )
