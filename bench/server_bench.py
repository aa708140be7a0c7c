"""`bench service`: how fast a real ``cloudbaking-server`` answers GI-map requests over loopback (misses, hits,
concurrent load), against its targets (docs/architecture.md, bench service)."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from baseline_cloudbaking.codecs import DEFAULT_CODEC, CodecName
from bench.common import Target
from bench.processes import pinned_server, scene_folder
from bench.runner import Bench, Block
from gicore import option_groups
from gicore.cores import client_cores, pinning
from gicore.present.declarations import Chart, Column, Derive, Figure, Rows, Table, Text, first, matches
from gicore.results import Results

SYSTEM = "cloud_baking"
STATS = ("median", "p95", "p99")


#: The service targets (the hit-time ones are stated at 256²).
TARGETS = (
    Target(
        "hit_server",
        "median",
        5.0,
        "ms",
        True,
        "cache hit inside the server (lookup + read) p50 <= 5 ms",
        (("part", "lookup_read"),),
    ),
    Target("hit_e2e", "median", 10.0, "ms", True, "hit end to end on loopback p50 <= 10 ms"),
    Target("load_errors", "value", 0.0, "count", True, "concurrent load: no errors"),
    Target("load_throughput", "value", 300.0, "req/s", False, "concurrent load >= 300 requests/s"),
)


@dataclass(frozen=True)
class ServiceConfig:
    """What one service run measures (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="the one the server bakes and serves")
    resolution: int = option_groups.resolution(note="of the GI maps; the targets are stated at 256")
    #: GI-map codec.
    codec: CodecName = DEFAULT_CODEC
    spp: int = option_groups.spp(note="of each baked map; only the misses pay for it")
    #: Distinct GI cameras baked by the misses and cycled over by the hits.
    views: int = 5
    #: Timed sequential hit requests from one client.
    sequential: int = 200
    #: Concurrent clients of the load phase.
    concurrency: int = 32
    #: Hit requests each concurrent client sends.
    per_client: int = 50
    #: Pin the server and the bench's client threads to separate cores (taskset) where the machine has them.
    pin: bool = True
    #: Read timeout of one request, s (bounds a miss's render).
    read_timeout_s: float = 600.0

    @classmethod
    def quick(cls) -> ServiceConfig:
        return cls(spp=16, sequential=50, per_client=20)


def _summary(add: Callable[..., None], metric: str, samples_ms: list[float], **config: Any) -> None:
    """Median, p95, p99, n and each sample of ``samples_ms``."""
    ms = np.asarray(samples_ms, dtype=np.float64)
    for stat, q in zip(STATS, (50, 95, 99)):
        add(metric=metric, value=float(np.percentile(ms, q)), unit="ms", stat=stat, **config)
    add(metric=metric, value=len(ms), unit="count", stat="n", **config)
    for v in ms:
        add(metric=metric, value=float(v), unit="ms", stat="sample", **config)


def measure(cfg: ServiceConfig, res: Results) -> None:
    from baseline_cloudbaking.server.loadtest import http_client, path_requests, run_closed_loop, timed_post

    scene_arg = cfg.scenes[0]
    scene, scenes_dir = Path(scene_arg).stem, scene_folder(scene_arg)
    bodies = path_requests(scene_arg, cfg.views, cfg.resolution, cfg.codec, cfg.spp, res.seed)
    plan = pinning(cfg.pin)
    res.settings["pinning"] = plan
    common = {"resolution": cfg.resolution, "codec": cfg.codec, "spp": cfg.spp}
    add = partial(res.add, system=SYSTEM, scene=scene)
    res.out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="service_store_", dir=res.out))
    try:
        with (
            pinned_server(plan, work / "store", scenes_dir) as url,
            client_cores(plan),
            http_client(url, cfg.read_timeout_s) as client,
        ):
            misses: list[tuple[float, dict[str, float]]] = []
            for body in bodies:
                seconds, header = timed_post(client, body)
                if header.get("hit") is False:  # a view within the tolerance of an earlier one is no miss
                    misses.append((seconds * 1e3, header["timings_ms"]))
            if not misses:
                raise RuntimeError(f"none of the {len(bodies)} views missed: the store at {work} was not fresh")
            _misses(add, partial(res.add_timing, system=SYSTEM, scene=scene), misses, common)

            for body in bodies:  # warm-up: every view once, untimed
                timed_post(client, body)
            e2e, lookup_read, total = [], [], []
            for i in range(cfg.sequential):
                seconds, header = timed_post(client, bodies[i % len(bodies)])
                if header.get("hit") is not True:
                    raise RuntimeError(
                        f"a request for a baked view (view {i % len(bodies)}) did not hit: {header.get('timings_ms')}"
                    )
                e2e.append(seconds * 1e3)
                lookup_read.append(header["timings_ms"]["lookup"] + header["timings_ms"]["read"])
                total.append(header["timings_ms"]["total"])
            seq = common | {"views": len(bodies)}
            _summary(add, "hit_server", lookup_read, part="lookup_read", **seq)
            _summary(add, "hit_server", total, part="total", **seq)
            _summary(add, "hit_e2e", e2e, **seq)

            latencies, n_errors, wall, first_errors = run_closed_loop(
                url, bodies, cfg.concurrency, cfg.per_client, cfg.read_timeout_s
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load = common | {"clients": cfg.concurrency, "per_client": cfg.per_client, "views": len(bodies)}
    if latencies:
        _summary(add, "load_latency", [s * 1e3 for s in latencies], **load)
    requests = cfg.concurrency * cfg.per_client
    add(metric="load_errors", value=n_errors, unit="count", requests=requests, first_errors=first_errors, **load)
    add(metric="load_throughput", value=requests / wall, unit="req/s", wall_s=round(wall, 4), **load)
    for target in TARGETS:  # the targets, from the rows just measured
        measured = first(res.rows, target.metric, target.stat, **dict(target.where))
        target.record(add, measured, resolution=cfg.resolution, stated_at_resolution=256)


def _misses(
    add: Callable[..., None], timing: Callable[..., None], misses: list[tuple[float, dict]], common: dict
) -> None:
    """``miss_e2e`` and ``miss_server`` rows: the first miss (scene load and compile included) alone, the
    median and p95 over the others."""
    (first_ms, first_timings), warm = misses[0], misses[1:]
    add(metric="miss_e2e", value=first_ms, unit="ms", stat="first", **common)
    for part, ms in first_timings.items():
        add(metric="miss_server", value=ms, unit="ms", stat="first", part=part, **common)
    if warm:
        timing(metric="miss_e2e", samples_s=[ms / 1e3 for ms, _ in warm], **common)
        for part in first_timings:
            timing(metric="miss_server", samples_s=[t[part] / 1e3 for _, t in warm], part=part, **common)


# -- what it shows ------------------------------------------------------------------------------------------
#: The timed metrics the table shows, in order: (metric, part).
TIMED = (
    ("miss_e2e", None),
    *(("miss_server", p) for p in ("lookup", "render", "denoise", "encode", "total")),
    ("hit_server", "lookup_read"),
    ("hit_server", "total"),
    ("hit_e2e", None),
    ("load_latency", None),
)
#: The sequential hits' samples, drawn as distributions: (metric, part, name).
HITS = (
    ("hit_server", "lookup_read", "server lookup + read"),
    ("hit_server", "total", "server total"),
    ("hit_e2e", None, "end to end (loopback)"),
)


def timings(rows: Rows) -> list[dict]:
    """Each timed metric's first, p50, p95, p99 and n (those measured)."""
    out = []
    for metric, part in TIMED:
        where = {"part": part} if part else {}
        row = {"metric": metric, "part": part or ""}
        row |= {stat: first(rows, metric, stat, **where) for stat in ("first", "median", "p95", "p99", "n")}
        out += [row] if row["median"] is not None or row["first"] is not None else []
    return out


def targets(rows: Rows) -> list[dict]:
    """Each target with its figure (and unit, when it was measured) and whether it was met."""
    out = []
    for r in (r for r in rows if r["stat"] == "target_met"):
        c = r["config"]
        unit = c["bound_unit"] if c["measured"] is not None else None
        out.append(
            {"target": c["target"], "measured": c["measured"], "unit": unit, "met": "yes" if r["value"] else "MISSED"}
        )
    return out


def cdf(which: tuple[tuple[str, str | None, str], ...]) -> Derive:
    """The samples of each (metric, part, name) as a cumulative distribution."""

    def points(rows: Rows) -> list[dict]:
        out = []
        for metric, part, name in which:
            mine = sorted(r["value"] for r in rows if matches(r, metric, "sample") and r["config"].get("part") == part)
            out += [
                {"name": f"{name} (n={len(mine)})", "ms": v, "share": (i + 1) / len(mine)} for i, v in enumerate(mine)
            ]
        return out

    return points


def _load_title(rows: Rows) -> str:
    clients = next((r["config"] for r in rows if r["metric"] == "load_throughput"), {})
    return (
        f"{clients.get('clients')} clients x {clients.get('per_client')} hits: "
        f"{first(rows, 'load_throughput', 'value') or 0:.0f} req/s (target >= 300), "
        f"{first(rows, 'load_errors', 'value') or 0:.0f} errors"
    )


def _cdf_chart(points: Derive, title: Text) -> Chart:
    tip = "{name}: {ms:.3g} ms, {share:.0%} at or below"
    return Chart(points, "ms", "share", "{name}", xlog=True, xlabel="latency [ms]", ylabel="fraction of requests",
                 title=title, tip=tip)  # fmt: skip


PARTS = (
    Table(
        timings,
        (
            Column("metric", "{metric} (ms)"),
            Column("part", "{part}"),
            Column("first", "{first:.2f}"),
            Column("p50", "{median:.2f}"),
            Column("p95", "{p95:.2f}"),
            Column("p99", "{p99:.2f}"),
            Column("n", "{n:.0f}"),
        ),
        caption="Times in ms (first: the first miss, with its JIT compile).",
        notes=lambda rows: (
            f"load: {first(rows, 'load_throughput', 'value') or 0:.2f} requests/s, "
            f"{first(rows, 'load_errors', 'value') or 0:.0f} errors"
        ),
    ),
    Table(targets, (Column("target", "{target}"), Column("measured", "{measured:.2f} {unit}"), Column("met", "{met}"))),
    Figure(
        "service",
        (
            _cdf_chart(cdf(HITS), "Sequential cache hits (targets: server p50 <= 5 ms, e2e p50 <= 10 ms)"),
            _cdf_chart(cdf((("load_latency", None, "request latency"),)), _load_title),
        ),
    ),
)


BENCH = Bench(
    "service",
    ServiceConfig,
    measure,
    help="GI-map server hit/miss service times and concurrent load",
    readme=Block("Cloud-baking server", 80),
    parts=PARTS,
    needs=("hit_e2e", "miss_e2e"),
)
