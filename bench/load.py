"""`bench load`: a ``cloudbaking-server`` under many clients at once, against the service's absolute targets.

One run starts ``cloudbaking-server`` as its own process on 127.0.0.1 (an ephemeral port, a fresh GI tree in a
temporary folder under ``--out``, removed afterwards; sharing the cores with the load generator unless ``--pin``)
and drives it with the load generator (:mod:`baseline_cloudbaking.server.loadtest`): ``hit_clients``
keep-alive clients each ask for one stored view every ``period_ms``, in three phases, each with its own side load
sent by a second process:

- ``alone``: none, for ``reference_s`` (the reference);
- ``misses``: ``misses`` new views at once; beyond ``--miss-queue`` they are answered 503 + Retry-After;
- ``idle``: ``idle`` connections that send nothing, ``idle_rate`` a second (at most what the file-descriptor
  limit holds; the row says how many were opened).

Rows per phase, its load in their config (with ``side_s``: how long the side load ran, from sending it to
``settle_s`` after its last answer or connection): ``hit_latency`` (ms; median, p99, max and n of the hits sent
while the side load ran), ``errors`` (hits not answered 200, misses answered neither 200 nor 503 with
Retry-After, connections that failed), ``miss_status`` (count per status) and ``connections`` (the server's
counters: accepted, drained, timed_out, refused). Each target gets a row ``stat = target_met`` (1 or 0; the load it
is stated at and the load it was run at in its config); a missed target is reported, not an error. Also written:
``load.md``.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from baseline_cloudbaking.server.settings import check_served
from bench.common import Target
from bench.processes import pinned_server, scene_folder
from bench.runner import Bench, Block
from gicore import option_groups
from gicore.cores import client_cores, pinning
from gicore.present.declarations import Column, Rows, Table, matches
from gicore.results import Results

if TYPE_CHECKING:
    from baseline_cloudbaking.server.loadtest import LoadResult

SYSTEM = "cloud_baking"
PHASES = ("alone", "misses", "idle")


@dataclass(frozen=True)
class LoadConfig:
    """What one load run sends (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="the one the server bakes and serves")
    resolution: int = option_groups.resolution(64, note="of the GI map of every request")
    spp: int = option_groups.spp(4, note="of each baked map; only the misses pay for it")
    #: Keep-alive clients asking for the one stored view.
    hit_clients: int = 32
    #: Time between one hit client's requests, ms.
    period_ms: float = 20.0
    #: New views sent at once in the misses phase (at most 200: more would stand within a stored map's tolerance).
    misses: int = field(default=80, metadata={"max": 200})
    #: Misses that may wait for the renderer (cloudbaking-server --miss-queue).
    miss_queue: int = field(default=8, metadata={"min": 0})
    #: Idle connections opened in the idle phase (at most what the file-descriptor limit holds).
    idle: int = 20_000
    #: Idle connections opened a second.
    idle_rate: float = 2000.0
    #: Open connections the server keeps (cloudbaking-server --max-connections).
    max_connections: int = field(default=1024, metadata={"min": 8})
    #: Seconds the hit clients run before each side load and after it.
    settle_s: float = 3.0
    #: Seconds the reference phase (``alone``) measures: as long as a side load lasts, so that its p99 is as
    #: sensitive to one stall of the machine as theirs.
    reference_s: float = 5.0
    #: Pin the server and the load generator to separate cores (taskset). Off: the targets are stated with both
    #: sharing every core, as on one machine; on 2 cores pinning leaves each of them one.
    pin: bool = False

    @classmethod
    def quick(cls) -> LoadConfig:
        return cls(idle=2000, settle_s=1.0, reference_s=3.0)


#: The targets, each with the load it is stated at.
TARGETS = (
    (Target("hit_latency", "p99", 50.0, "ms", True, "hit p99 <= 50 ms with 80 misses + 32 hit clients (1,600 hits/s)",
            (("phase", "misses"),)), {"misses": 80, "hit_clients": 32, "period_ms": 20.0}),
    (Target("hit_latency", "p99", 50.0, "ms", True, "hit p99 <= 50 ms beside 20,000 idle connections",
            (("phase", "idle"),)), {"idle": 20_000, "hit_clients": 32, "period_ms": 20.0}),
    (Target("errors", "value", 0.0, "count", True, "no errors: hits 200, misses 200 or 503 + Retry-After"), {}),
)  # fmt: skip


def _stats(url: str) -> dict[str, Any]:
    import httpx

    return httpx.get(f"{url}/v1/stats", timeout=60.0).json()


def _phase(url: str, cfg: LoadConfig, phase: str, hit: dict[str, Any], idle: int) -> tuple[LoadResult, dict[str, int]]:
    """One phase's :class:`~baseline_cloudbaking.server.loadtest.LoadResult` and the server's counters over it."""
    from baseline_cloudbaking.server.limits import COUNTERS
    from baseline_cloudbaking.server.loadtest import miss_requests, run_interruptibly, run_load

    misses = miss_requests(hit["scene"], cfg.resolution, cfg.spp, cfg.misses) if phase == "misses" else []
    before = _stats(url)
    res = run_interruptibly(
        run_load(url, hit, misses, hit_clients=cfg.hit_clients, period_s=cfg.period_ms / 1e3,
                 idle=idle if phase == "idle" else 0, idle_rate=cfg.idle_rate, settle_s=cfg.settle_s,
                 hold_s=cfg.reference_s if phase == "alone" else None, max_s=3600.0, keep=cfg.max_connections)
    )  # fmt: skip
    after = _stats(url)
    return res, {k: after[k] - before[k] for k in COUNTERS}


def measure(cfg: LoadConfig, res: Results) -> None:
    from baseline_cloudbaking.server.loadtest import hit_request, idle_room, run_interruptibly, store

    check_served(cfg.resolution)
    scene_arg = cfg.scenes[0]
    scene = Path(scene_arg).stem
    idle = min(cfg.idle, idle_room())
    if idle < cfg.idle:
        print(f"note: {idle} idle connections, not {cfg.idle}: the file-descriptor limit (ulimit -Hn)", file=sys.stderr)
    plan = pinning(cfg.pin)
    res.settings["pinning"] = plan
    options = ("--miss-queue", str(cfg.miss_queue), "--max-connections", str(cfg.max_connections))
    hit = hit_request(scene, cfg.resolution, cfg.spp)
    res.out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="load_store_", dir=res.out))
    try:
        with pinned_server(plan, work / "store", scene_folder(scene_arg), *options) as url, client_cores(plan):
            run_interruptibly(store(url, hit))  # compiles the renderer: every miss after it costs one render
            for phase in PHASES:
                _record(res, cfg, scene, phase, *_phase(url, cfg, phase, hit, idle))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    _targets(res, scene)


def _record(res: Results, cfg: LoadConfig, scene: str, phase: str, load: LoadResult, counters: dict[str, int]) -> None:
    """A phase's rows (module docstring); its load is in every row's config."""
    config = {"phase": phase, "hit_clients": cfg.hit_clients, "period_ms": cfg.period_ms,
              "offered_per_s": round(cfg.hit_clients * 1e3 / cfg.period_ms, 1), "resolution": cfg.resolution,
              "misses": len(load.misses) if phase == "misses" else 0, "idle": load.idle_opened,
              "side_s": round(load.side_window[1] - load.side_window[0], 2)}  # fmt: skip
    add = partial(res.add, system=SYSTEM, scene=scene, **config)
    ms = np.asarray(load.hits_sent_between(*load.side_window) or [np.nan])
    for stat, value in (("median", np.median(ms)), ("p99", np.percentile(ms, 99)), ("max", np.max(ms))):
        add(metric="hit_latency", value=float(value), unit="ms", stat=stat)
    add(metric="hit_latency", value=int(np.isfinite(ms).sum()), unit="count", stat="n")
    first = [f"{k}: {v}" for k, v in list(load.errors.items())[:5]]
    add(metric="errors", value=load.failures(), unit="count", first=first)
    for status, count in sorted(load.miss_status.items()):
        add(metric="miss_status", value=count, unit="count", status=status)
    for counter, count in counters.items():
        add(metric="connections", value=count, unit="count", counter=counter.removeprefix("connections_"))


def _targets(res: Results, scene: str) -> None:
    """One ``target_met`` row per target, from the rows just measured (the errors target: over every phase)."""
    for target, stated_at in TARGETS:
        where = dict(target.where)
        found = [r for r in res.rows if matches(r, target.metric, target.stat, **where)]
        measured = sum(r["value"] for r in found) if target.metric == "errors" else next(
            (r["value"] for r in found), None)  # fmt: skip
        load = {k: found[0]["config"][k] for k in stated_at} if found and stated_at else {}
        target.record(partial(res.add, system=SYSTEM, scene=scene), measured, stated_at=stated_at, run_at=load,
                      at_stated_load=at_least(load, stated_at), **where)  # fmt: skip


def at_least(load: dict[str, float], stated: dict[str, float]) -> bool:
    """Whether ``load`` is at least the ``stated`` one: as many clients, misses and idle connections or more,
    each client asking as often or more."""
    return all(load[k] <= v if k == "period_ms" else load[k] >= v for k, v in stated.items())


# -- what it shows ------------------------------------------------------------------------------------------
def phases(rows: Rows) -> list[dict]:
    """Each phase's load, and its hits' count, p50, p99 and max latency and its errors."""
    out = []
    for phase in PHASES:
        mine = [r for r in rows if r["config"].get("phase") == phase and r["stat"] != "target_met"]
        if mine:
            c = mine[0]["config"]
            side = {"alone": "", "misses": f" + {c['misses']} misses", "idle": f" + {c['idle']} idle"}[phase]
            value = {f"{r['metric']}_{r['stat']}": r["value"] for r in mine}
            out.append(
                {"phase": phase, "load": f"{c['hit_clients']} clients, {c['offered_per_s']:g} hits/s{side}", **value}
            )
    return out


def targets(rows: Rows) -> list[dict]:
    """Each target with its figure (its unit when measured), the load it ran at and its verdict."""
    out = []
    for r in (r for r in rows if r["stat"] == "target_met"):
        c = r["config"]
        verdict = ("met" if r["value"] else "not met") + ("" if c["at_stated_load"] else " (at a lighter load)")
        at = ", ".join(f"{k} {v:g}" for k, v in c["run_at"].items()) or "every phase"
        unit = None if c["measured"] is None else c["bound_unit"]
        out.append({"target": c["target"], "measured": c["measured"], "unit": unit, "at": at, "verdict": verdict})
    return out


PARTS = (
    Table(
        phases,
        (
            Column("phase", "{phase}"),
            Column("load", "{load}"),
            Column("hits", "{hit_latency_n:.0f}"),
            Column("p50 (ms)", "{hit_latency_median:.1f}"),
            Column("p99 (ms)", "{hit_latency_p99:.1f}"),
            Column("max (ms)", "{hit_latency_max:.1f}"),
            Column("errors", "{errors_value:.0f}"),
        ),
        caption="Hit latency while each side load ran.",
    ),
    Table(
        targets,
        (
            Column("target", "{target}"),
            Column("measured", "{measured:.1f} {unit}"),
            Column("at", "{at}"),
            Column("met", "{verdict}"),
        ),
    ),
)


BENCH = Bench(
    "load",
    LoadConfig,
    measure,
    help="GI-map server under load: hit p99 with 80 misses + 32 hit clients and beside 20,000 idle connections, "
    "against the 50 ms targets",
    readme=Block("Cloud-baking server under load", 85),
    parts=PARTS,
    needs=("hit_latency", "errors"),
)
