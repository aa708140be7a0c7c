"""`bench scaling`: the render executor (``gicore.executor``) with 1 and 2 workers, local processes against Ray
on one node and against a simulated Ray cluster, and what the measured cost projects for the paper's data set
and for baking GI trees (``stat = projection``, never a measurement; docs/architecture.md, bench scaling)."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import dataclass
from functools import partial
from typing import Any, Literal

from bench.runner import Bench, Block
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.executor import INSTALL_RAY, Executor, LocalPool, RayExecutor, Task, local_ray, simulated_ray_cluster
from gicore.present.declarations import Chart, Column, Figure, Rows, Table, flat, matches, per, unique
from gicore.results import Results
from gicore.scene import builtin_scenes, load_scene

Kind = Literal["frame", "map"]
UNITS = {"frame": "frames/s", "map": "maps/s"}
#: The executor on a simulated Ray cluster: as many nodes of 1 CPU as the largest worker count.
CLUSTER = "ray-cluster"
#: The scene column of totals over the paper's five scenes.
ALL = "paper_5_scenes"
#: What every projection row assumes, stated in its config.
ASSUMPTION = "ceil(items/N) x 1-worker item time x pixel ratio; linear scaling, no startup"


@dataclass(frozen=True)
class ScalingConfig:
    """What one scaling run renders and projects."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="its cost stands for every scene in the projections")
    resolution: int = option_groups.resolution(note="of the measured frames and maps; projections scale by pixel count")
    spp: int = option_groups.spp(note="of frames and maps, then OIDN; measured and projected")
    #: Data-set frames timed per point (after two warm-up frames per worker).
    frames: int = 8
    #: GI maps timed per point (after two warm-up maps per worker).
    maps: int = 4
    #: Worker counts (single-threaded processes).
    workers: tuple[int, ...] = (1, 2)
    #: Executors compared: local spawned processes, Ray tasks on a local instance, Ray tasks on a cluster simulated
    #: on this machine with one 1-CPU node per worker of the largest count (a point of N workers keeps N tasks in
    #: flight on it).
    executors: tuple[Literal["local", "ray", "ray-cluster"], ...] = ("local", "ray", CLUSTER)
    #: No-op jobs timed for the per-task overhead.
    overhead_jobs: int = 100
    #: Worker counts of the projections.
    project_workers: tuple[int, ...] = (1, 2, 8, 32, 128, 512)
    #: Projected data set: frames per scene (paper: 1500 training + 100 validation) over the five scenes.
    project_frames: int = 1600
    #: Projected data-set resolution (paper: 512).
    project_resolution: int = 512
    #: Projected bake: fly-through frames per scene (paper: 1500).
    bake_frames: int = 1500
    #: Projected GI-map resolution (cloudbaking-prebake's default).
    bake_resolution: int = 256

    @classmethod
    def quick(cls) -> ScalingConfig:
        return cls(resolution=64, spp=16, frames=16, maps=8, overhead_jobs=40)

    def check(self) -> None:
        on_ray = [ex for ex in self.executors if ex != "local"]
        if on_ray:
            try:
                import ray  # noqa: F401
            except ImportError:
                raise UserError(f"--executors {on_ray[0]} needs Ray, which is not installed", INSTALL_RAY) from None


def _nothing() -> None:
    """State of the no-op task."""


def _echo(_: None, job: int) -> int:
    return job


def _tasks(cfg: ScalingConfig, name: str, seed: int, n: int) -> dict[Kind, tuple[Task, list]]:
    """The data-set frame task and the prebake map task of scene ``name`` with ``n`` jobs each, built as
    gicore-dataset and cloudbaking-prebake build them."""
    from baseline_cloudbaking.bake import fly_through
    from baseline_cloudbaking.prebake_cli import PrebakeConfig, bake_jobs, bake_task
    from gicore.dataset_cli import DatasetConfig, frame_jobs, frame_task, plan_frames

    spec = load_scene(name)
    data = DatasetConfig(n_train=n, n_val=0, resolution=cfg.resolution, spp=cfg.spp, denoise=True, seed=seed)
    bake = PrebakeConfig(frames=n, resolution=cfg.resolution, spp=cfg.spp, seed=seed)
    path = fly_through(spec, n, cfg.resolution, bake.light_cell, seed)
    return {
        "frame": (frame_task(spec, data), frame_jobs(plan_frames(spec, data), data)),
        "map": (bake_task(spec, spec.name, bake), bake_jobs(path, range(n), spec.name, seed)),
    }


def _wall(executor: Executor, task: Task, jobs: list) -> float:
    """Seconds from submitting ``jobs`` to receiving the last result."""
    t0 = time.perf_counter()
    executor.run(task, jobs, lambda job, result: None)
    return time.perf_counter() - t0


@contextmanager
def _ray_instance(res: Results, name: str, num_cpus: int) -> Iterator[None]:
    """A local Ray instance of ``num_cpus`` CPUs for the ``ray`` points (its start time recorded); its workers run
    at this process's priority, as the local pool's: a like-for-like comparison on a busy machine."""
    t0 = time.perf_counter()
    with local_ray(num_cpus):
        res.add(system="ray", scene=name, metric="instance_start", value=time.perf_counter() - t0, unit="s",
                num_cpus=num_cpus)  # fmt: skip
        yield


@contextmanager
def _ray_cluster(res: Results, name: str, nodes: int) -> Iterator[None]:
    """A Ray cluster of ``nodes`` nodes of 1 CPU each simulated on this machine, this process its driver
    (its start time recorded); every node stopped at the end."""
    t0 = time.perf_counter()
    with simulated_ray_cluster(nodes):
        res.add(system=CLUSTER, scene=name, metric="instance_start", value=time.perf_counter() - t0, unit="s",
                nodes=nodes)  # fmt: skip
        yield


@contextmanager
def _executor(kind: str, workers: int) -> Iterator[Executor]:
    """``workers`` single-threaded workers of executor ``kind`` (on Ray: the instance or cluster that
    :func:`_ray_for` started)."""
    if kind == "local":
        with LocalPool(workers, threads=1) as pool:
            yield pool
    else:
        yield RayExecutor(workers, threads=1)


def _ray_for(kind: str, cfg: ScalingConfig, res: Results, name: str) -> AbstractContextManager[None]:
    """What executor ``kind`` runs on for all its points: one Ray instance or cluster, started once, or nothing."""
    if kind == "ray":
        return _ray_instance(res, name, max(cfg.workers))
    if kind == CLUSTER:
        return _ray_cluster(res, name, max(cfg.workers))
    return nullcontext()


def measure(cfg: ScalingConfig, res: Results) -> None:
    name = cfg.scenes[0]
    warm = 2 * max(cfg.workers)
    tasks = _tasks(cfg, name, res.seed, warm + max(cfg.frames, cfg.maps))
    counts: dict[Kind, int] = {"frame": cfg.frames, "map": cfg.maps}
    common = {"resolution": cfg.resolution, "spp": cfg.spp, "threads_per_worker": 1}
    item_s: dict[tuple[str, Kind], float] = {}
    for ex in cfg.executors:
        with _ray_for(ex, cfg, res, name):
            for workers in sorted(cfg.workers):
                with _executor(ex, workers) as executor:
                    _overhead(res, ex, name, executor, cfg.overhead_jobs)
                    for kind, (task, jobs) in tasks.items():
                        warmup = _wall(executor, task, jobs[:warm])
                        if isinstance(executor, RayExecutor):
                            executor.nodes.clear()
                        wall = _wall(executor, task, jobs[warm : warm + counts[kind]])
                        config = common | {"workers": workers, "kind": kind, "items": counts[kind]}
                        add = partial(res.add, system=ex, scene=name)
                        add(metric="warmup", value=warmup, unit="s", **config | {"items": warm})
                        add(metric="throughput", value=counts[kind] / wall, unit=UNITS[kind], **config)
                        add(metric="item_time", value=workers * wall / counts[kind], unit="s", **config)
                        if isinstance(executor, RayExecutor) and ex == CLUSTER:  # nodes that ran the timed items
                            add(metric="nodes_used", value=len(executor.nodes), unit="count", **config)
                        if workers == 1:
                            item_s[ex, kind] = wall / counts[kind]
                        elif (ex, kind) in item_s:
                            efficiency = item_s[ex, kind] * counts[kind] / (workers * wall)
                            add(metric="efficiency", value=efficiency, unit="ratio", **config)
    _project(cfg, res, name, item_s)


def _overhead(res: Results, ex: str, name: str, executor: Executor, n: int) -> None:
    """The no-op task: one job at a time (round trip), then ``n`` submitted at once (ms per job); each
    after an untimed warm-up batch (worker start, imports)."""
    noop = Task(_nothing, (), _echo)
    _wall(executor, noop, list(range(2 * executor.workers)))
    samples = [_wall(executor, noop, [i]) for i in range(n)]
    res.add_timing(system=ex, scene=name, metric="task_roundtrip", samples_s=samples, workers=executor.workers)
    ms = _wall(executor, noop, list(range(n))) / n * 1e3
    res.add(
        system=ex, scene=name, metric="task_overhead_batched", value=ms, unit="ms", workers=executor.workers, jobs=n
    )


def prebake_maps(space: Literal["fly-through", "all"], frames: int, resolution: int) -> dict[str, int]:
    """Maps a ``cloudbaking-prebake --space SPACE`` of each built-in scene bakes into an empty store (a
    ``frames``-frame fly-through, or the whole configuration space; default tolerance and light cell)."""
    from baseline_cloudbaking.prebake_cli import PrebakeConfig, maps_to_bake

    cfg = PrebakeConfig(frames=frames, resolution=resolution, space=space)
    return {scene: maps_to_bake(load_scene(scene), cfg) for scene in builtin_scenes()}


def _project(cfg: ScalingConfig, res: Results, name: str, item_s: dict[tuple[str, Kind], float]) -> None:
    """Projection rows (see the module docstring) from each executor's 1-worker item times."""
    maps = prebake_maps("fly-through", cfg.bake_frames, cfg.bake_resolution)
    for scene, n in maps.items():
        res.add(
            system="plan", scene=scene, metric="bake_maps", value=n, unit="count", fly_through_frames=cfg.bake_frames
        )
    space = prebake_maps("all", cfg.bake_frames, cfg.bake_resolution)
    for scene, n in space.items():
        res.add(system="plan", scene=scene, metric="space_maps", value=n, unit="count")
    targets: list[tuple[Kind, str, int, dict[str, int]]] = [
        ("frame", "dataset_wall", cfg.project_resolution, {ALL: cfg.project_frames * len(builtin_scenes())}),
        ("map", "bake_wall", cfg.bake_resolution, maps),
        ("map", "space_wall", cfg.bake_resolution, space),
    ]
    for (ex, measured_kind), measured in item_s.items():
        for kind, metric, resolution, items in targets:
            if kind == measured_kind:
                _project_one(cfg, res, name, ex, measured, metric, resolution, items)


def _project_one(
    cfg: ScalingConfig,
    res: Results,
    name: str,
    ex: str,
    measured: float,
    metric: str,
    resolution: int,
    items: dict[str, int],
) -> None:
    """The ``metric`` projection rows of executor ``ex`` for ``items`` per scene at ``resolution``."""
    scale = (resolution / cfg.resolution) ** 2
    basis = {
        "measured_on": name,
        "measured_resolution": cfg.resolution,
        "measured_item_s": measured,
        "pixel_scale": scale,
    }
    basis |= {"resolution": resolution, "spp": cfg.spp, "item_s": measured * scale, "assumption": ASSUMPTION}
    for workers in cfg.project_workers:
        hours = {scene: math.ceil(n / workers) * measured * scale / 3600 for scene, n in items.items()}
        if ALL not in hours:  # the bake: scene after scene
            hours[ALL] = sum(hours.values())
        for scene, value in hours.items():
            n = items.get(scene, sum(items.values()))
            res.add(
                system=ex,
                scene=scene,
                metric=metric,
                stat="projection",
                value=value,
                unit="h",
                workers=workers,
                items=n,
                **basis,
            )


#: Projection metrics and how the tables name them.
PROJECTED = {
    "dataset_wall": "the paper's data set",
    "bake_wall": "GI-tree bakes of 5 scenes",
    "space_wall": "whole configuration spaces of 5 scenes",
}


# -- what it shows ------------------------------------------------------------------------------------------
def _cluster_nodes(rows: Rows) -> int:
    """Nodes of the run's simulated cluster (0 without one)."""
    return max(
        (r["config"]["nodes"] for r in rows if matches(r, "instance_start") and r["system"] == CLUSTER), default=0
    )


def _label(ex: str, nodes: int) -> str:
    """An executor's row name: the cluster's names its ``nodes`` simulated nodes."""
    return f"ray, {nodes} nodes x 1 CPU (simulated)" if ex == CLUSTER else ex


def _executors(rows: Rows) -> list[str]:
    return unique(r["system"] for r in rows if r["metric"] == "throughput")


def _projected_on(executors: list[str]) -> list[str]:
    """Executors the projection tables show: the projections follow from the 1-worker item time, and one task at
    a time on the simulated cluster is the ``ray`` instance's again."""
    return [ex for ex in executors if ex != CLUSTER] or executors


def _value(rows: list[dict], **match: Any) -> float:
    """The value of the one row whose fields (and config keys) match, else NaN."""
    for row in rows:
        if all((row[k] if k in row else row["config"].get(k)) == v for k, v in match.items()):
            return float(row["value"])
    return float("nan")


def measured(rows: Rows) -> list[dict]:
    """Per executor and worker count: frames/s, maps/s, efficiency against 1 worker, the no-op task's round trip
    and its batched cost."""
    out, nodes = [], _cluster_nodes(rows)
    for ex in _executors(rows):
        for w in sorted({r["config"]["workers"] for r in rows if r["metric"] == "throughput"}):
            get = partial(_value, rows, system=ex, workers=w)
            row = {"label": _label(ex, nodes), "workers": w, "trip": get(metric="task_roundtrip", stat="median")}
            row |= {"frames": get(metric="throughput", kind="frame"), "maps": get(metric="throughput", kind="map")}
            row["efficiency"] = 1.0 if w == 1 else get(metric="efficiency", kind="frame")
            out.append(row | {"batched": get(metric="task_overhead_batched")})
    return out


def cluster_note(rows: Rows) -> str:
    """The cluster's sentence: maps/s and the no-op round trip with 2 tasks in flight against 1, nodes used."""
    one, two = (_value(rows, system=CLUSTER, metric="throughput", workers=n, kind="map") for n in (1, 2))
    if math.isnan(two):
        return ""
    trips = [_value(rows, system=CLUSTER, metric="task_roundtrip", stat="median", workers=n) for n in (1, 2)]
    used = _value(rows, system=CLUSTER, metric="nodes_used", workers=2, kind="map")
    nodes = _cluster_nodes(rows)
    return (
        f"A simulated Ray cluster of {nodes} nodes (1 CPU each, sharing this machine's cores): {two:.3g} maps/s with "
        f"2 tasks in flight against {one:.3g} with 1 ({two / one:.2f}x); no-op task round trip {trips[1]:.3g} ms "
        f"against {trips[0]:.3g} ms; {used:.0f} of {nodes} nodes ran the 2 tasks' timed maps."
    )


def _projections(rows: Rows) -> list[tuple[str, str]]:
    """(executor, metric) of each projection column."""
    shown = [m for m in PROJECTED if any(r["metric"] == m and r["stat"] == "projection" for r in rows)]
    return [(ex, m) for ex in _projected_on(_executors(rows)) for m in shown]


def projected(rows: Rows) -> list[dict]:
    """Per worker count, the projected wall hours of each projection column."""
    mine = [r for r in rows if r["stat"] == "projection" and r["scene"] == ALL]
    workers = sorted({r["config"]["workers"] for r in mine})
    return [
        {"n": n, "h": [_value(mine, system=ex, metric=m, workers=n) for ex, m in _projections(rows)]} for n in workers
    ]


def _projected_caption(rows: Rows) -> str:
    mine = [r for r in rows if r["stat"] == "projection" and r["scene"] == ALL]
    what = {r["metric"]: r["config"] for r in mine}
    shown = "; ".join(
        f"{PROJECTED[m]}: {what[m].get('items')} items at {what[m].get('resolution')}²" for m in PROJECTED if m in what
    )
    return f"PROJECTED, not measured: wall hours on N workers ({shown}; {mine[0]['config'].get('assumption')})."


def _measured_caption(rows: Rows) -> str:
    r = next(r for r in rows if r["metric"] == "throughput")
    c = r["config"]
    return f"Measured on {r['scene']} at {c.get('resolution')}², {c.get('spp')} spp + OIDN, single-threaded workers."


def _bars(rows: Rows) -> list[dict]:
    return [
        flat(r)
        | {
            "at": f"{r['config']['workers']} worker{'s' * (r['config']['workers'] > 1)}",
            "name": f"{r['system']}: {r['unit']}",
        }
        for r in rows
        if matches(r, "throughput")
    ]


def _maps(rows: Rows) -> list[dict]:
    named = {CLUSTER: "Ray nodes of 1 CPU (simulated)"}
    return [
        flat(r) | {"name": named.get(r["system"], f"{r['system']}: workers on one node")}
        for r in rows
        if matches(r, "throughput", kind="map")
    ]


def _projection_points(rows: Rows) -> list[dict]:
    on = _projected_on(_executors(rows))
    return [
        flat(r) | {"name": f"{PROJECTED[r['metric']]} ({r['system']})"}
        for r in rows
        if r["stat"] == "projection" and r["scene"] == ALL and r["system"] in on
    ]


PARTS = (
    Table(
        measured,
        (
            Column("executor", "{label}"),
            Column("workers", "{workers}"),
            Column("frames/s", "{frames:.3g}"),
            Column("maps/s", "{maps:.3g}"),
            Column("efficiency (frames, against 1 worker)", "{efficiency:.2f}"),
            Column("no-op task round trip ms (median)", "{trip:.3g}"),
            Column("no-op batched ms per job", "{batched:.3g}"),
        ),
        caption=_measured_caption,
        notes=cluster_note,
    ),
    Table(
        projected,
        lambda rows: (
            Column("N workers", "{n}"),
            *per((f"{PROJECTED[m]}, {ex} [h]" for ex, m in _projections(rows)), "{}", "{h[#]:.3g}"),
        ),
        caption=_projected_caption,
    ),
    Figure(
        "scaling",
        (
            Chart(
                _bars,
                "at",
                series="{name}",
                kind="bar",
                ylabel="items per second (measured)",
                title="Measured throughput",
            ),
            Chart(
                _maps,
                "workers",
                series="{name}",
                xlabel="workers (tasks in flight)",
                ylabel="maps per second (measured)",
                title="maps/s against Ray nodes (they share this machine's cores)",
            ),
            Chart(
                _projection_points,
                "workers",
                series="{name}",
                xlog=True,
                ylog=True,
                xlabel="workers (single-threaded)",
                ylabel="PROJECTED wall time [h]",
                title="PROJECTION from the measured 1-worker cost (linear scaling assumed)",
            ),
        ),
    ),
)


BENCH = Bench(
    "scaling",
    ScalingConfig,
    measure,
    help="Render executor: frames/maps per second with 1 and 2 workers, local processes vs Ray vs Ray nodes (a cluster "
    "simulated on this machine), per-task overhead, and the projected wall time of the paper's data set, of GI-tree "
    "bakes and of whole configuration spaces on N workers.",
    readme=Block("Scaling", 110),
    parts=PARTS,
    needs=("throughput",),
)
