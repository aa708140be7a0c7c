"""`bench scaling`: the render executor (``gicore.executor``) with 1 and 2 workers, local processes
against Ray on one node and against a Ray cluster of one 1-CPU node per worker, and what the measured
cost projects for the paper's data set and for baking GI trees.

Measured on the real tasks of ``gicore-dataset`` and ``cloudbaking-prebake``, single-threaded workers, after
two warm-up items per worker: ``throughput``, ``item_time``, ``efficiency``, the per-task overhead
(``task_roundtrip``, ``task_overhead_batched``), ``instance_start`` and ``warmup``. The simulated cluster's
nodes share this machine's cores, so they measure a node's overhead, not a second machine's speed. Projected
(``stat = projection``, never a measurement): wall time on N workers as ``ceil(items / N) x item_time`` scaled
by pixels. docs/architecture.md, bench scaling.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bench.runner import Bench, Block, Rows, Table, cell, need, pick
from gicore.error_policy import UserError
from gicore.executor import INSTALL_RAY, Executor, LocalPool, RayExecutor, Task
from gicore.results import Results, read_rows
from gicore.scene import builtin_scenes, load_scene

Kind = Literal["frame", "map"]
UNITS = {"frame": "frames/s", "map": "maps/s"}
#: The executor whose N workers are N simulated Ray nodes of 1 CPU each.
CLUSTER = "ray-cluster"
#: The scene column of totals over the paper's five scenes.
ALL = "paper_5_scenes"
#: What every projection row assumes, stated in its config.
ASSUMPTION = "ceil(items/N) x 1-worker item time x pixel ratio; linear scaling, no startup"


@dataclass(frozen=True)
class ScalingConfig:
    """What one scaling run renders and projects."""

    #: The scene rendered (one; its cost stands for every scene in the projections).
    scenes: tuple[str, ...] = field(default=("lung_plane",), metadata={"max_len": 1})
    #: Square resolution of the measured frames and maps (projections scale by pixel count).
    resolution: int = 256
    #: Path-tracing samples per pixel of frames and maps (then OIDN), measured and projected.
    spp: int = 64
    #: Data-set frames timed per point (after two warm-up frames per worker).
    frames: int = 8
    #: GI maps timed per point (after two warm-up maps per worker).
    maps: int = 4
    #: Worker counts (single-threaded processes).
    workers: tuple[int, ...] = (1, 2)
    #: Executors compared: local spawned processes, Ray tasks on a local instance, Ray tasks on a cluster of one
    #: 1-CPU node per worker simulated on this machine.
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
    """A local Ray instance of ``num_cpus`` CPUs for the ``ray`` points (its start time recorded)."""
    import ray

    t0 = time.perf_counter()
    ray.init(
        address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR
    )
    try:
        start = time.perf_counter() - t0
        res.add(system="ray", scene=name, metric="instance_start", value=start, unit="s", num_cpus=num_cpus)
        yield
    finally:
        ray.shutdown()


@contextmanager
def _ray_cluster(res: Results, name: str, nodes: int) -> Iterator[None]:
    """A Ray cluster of ``nodes`` nodes of 1 CPU each simulated on this machine, this process its driver
    (its start time recorded); every node stopped at the end."""
    import ray
    from ray.cluster_utils import Cluster

    t0 = time.perf_counter()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        for _ in range(nodes - 1):
            cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, log_to_driver=False, logging_level=logging.ERROR)
        start = time.perf_counter() - t0
        res.add(system=CLUSTER, scene=name, metric="instance_start", value=start, unit="s", nodes=nodes)
        yield
    finally:
        ray.shutdown()
        cluster.shutdown()


@contextmanager
def _executor(kind: str, workers: int, res: Results, name: str) -> Iterator[Executor]:
    """``workers`` single-threaded workers of executor ``kind`` (``ray``: on the instance :func:`measure`
    started; ``ray-cluster``: on a cluster of ``workers`` nodes started for this point)."""
    if kind == "local":
        with LocalPool(workers, threads=1) as pool:
            yield pool
    elif kind == "ray":
        yield RayExecutor(workers, threads=1)
    else:
        with _ray_cluster(res, name, workers):
            yield RayExecutor(workers, threads=1)


def measure(cfg: ScalingConfig, res: Results) -> None:
    name = cfg.scenes[0]
    warm = 2 * max(cfg.workers)
    tasks = _tasks(cfg, name, res.seed, warm + max(cfg.frames, cfg.maps))
    counts: dict[Kind, int] = {"frame": cfg.frames, "map": cfg.maps}
    common = {"resolution": cfg.resolution, "spp": cfg.spp, "threads_per_worker": 1}
    item_s: dict[tuple[str, Kind], float] = {}
    for ex in cfg.executors:
        with _ray_instance(res, name, max(cfg.workers)) if ex == "ray" else nullcontext():
            for workers in sorted(cfg.workers):
                with _executor(ex, workers, res, name) as executor:
                    _overhead(res, ex, name, executor, cfg.overhead_jobs)
                    for kind, (task, jobs) in tasks.items():
                        warmup = _wall(executor, task, jobs[:warm])
                        if isinstance(executor, RayExecutor):
                            executor.nodes.clear()
                        wall = _wall(executor, task, jobs[warm : warm + counts[kind]])
                        config = common | {"workers": workers, "kind": kind, "items": counts[kind]}
                        res.add(
                            system=ex, scene=name, metric="warmup", value=warmup, unit="s", **config | {"items": warm}
                        )
                        res.add(
                            system=ex,
                            scene=name,
                            metric="throughput",
                            value=counts[kind] / wall,
                            unit=UNITS[kind],
                            **config,
                        )
                        res.add(
                            system=ex,
                            scene=name,
                            metric="item_time",
                            value=workers * wall / counts[kind],
                            unit="s",
                            **config,
                        )
                        if isinstance(executor, RayExecutor) and ex == CLUSTER:  # nodes that ran the timed items
                            used = len(executor.nodes)
                            res.add(system=ex, scene=name, metric="nodes_used", value=used, unit="count", **config)
                        if workers == 1:
                            item_s[ex, kind] = wall / counts[kind]
                        elif (ex, kind) in item_s:
                            efficiency = item_s[ex, kind] * counts[kind] / (workers * wall)
                            res.add(
                                system=ex, scene=name, metric="efficiency", value=efficiency, unit="ratio", **config
                            )
    _project(cfg, res, name, item_s)
    _write_table(cfg, res)


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


def bake_maps(frames: int, resolution: int) -> dict[str, int]:
    """Maps a prebake of each built-in scene's ``frames``-frame fly-through bakes into an empty store
    (the prebake's plan rule, default tolerance and light cell): counted, nothing rendered."""
    from baseline_cloudbaking.bake import fly_through
    from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL
    from baseline_cloudbaking.viewpoints import Tolerance, simulate_fill

    out = {}
    for scene in builtin_scenes():
        path = fly_through(load_scene(scene), frames, resolution, DEFAULT_LIGHT_CELL)
        out[scene] = len(set(simulate_fill([f.view for f in path], [f.cell for f in path], Tolerance())))
    return out


def space_maps() -> dict[str, int]:
    """Maps of each built-in scene's whole configuration space (``cloudbaking-prebake --space all`` at the
    default tolerance and light cell): counted, nothing rendered."""
    from baseline_cloudbaking.bake import configuration_space
    from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL
    from baseline_cloudbaking.viewpoints import Tolerance

    return {s: configuration_space(load_scene(s), Tolerance(), DEFAULT_LIGHT_CELL).size for s in builtin_scenes()}


def _project(cfg: ScalingConfig, res: Results, name: str, item_s: dict[tuple[str, Kind], float]) -> None:
    """Projection rows (see the module docstring) from each executor's 1-worker item times."""
    maps = bake_maps(cfg.bake_frames, cfg.bake_resolution)
    for scene, n in maps.items():
        res.add(
            system="plan", scene=scene, metric="bake_maps", value=n, unit="count", fly_through_frames=cfg.bake_frames
        )
    space = space_maps()
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


def _label(ex: str, workers: int) -> str:
    """An executor's row name: a cluster point names its simulated nodes."""
    return f"ray, {workers} node{'s' * (workers > 1)} x 1 CPU (simulated)" if ex == CLUSTER else ex


def _projected_on(executors: list[str]) -> list[str]:
    """Executors the projection tables show: a simulated cluster's 1-node point is the ``ray`` one again."""
    return [ex for ex in executors if ex != CLUSTER] or executors


def _two_nodes(rows: list[dict]) -> str | None:
    """The two-node sentence: maps/s and the no-op round trip of 2 simulated nodes against 1, nodes used."""
    one, two = (_value(rows, system=CLUSTER, metric="throughput", workers=n, kind="map") for n in (1, 2))
    if math.isnan(two):
        return None
    trips = [_value(rows, system=CLUSTER, metric="task_roundtrip", stat="median", workers=n) for n in (1, 2)]
    used = _value(rows, system=CLUSTER, metric="nodes_used", workers=2, kind="map")
    return (
        f"Two simulated Ray nodes (1 CPU each, sharing this machine's cores): {two:.3g} maps/s against {one:.3g} on "
        f"one node ({two / one:.2f}x); no-op task round trip {trips[1]:.3g} ms against {trips[0]:.3g} ms; "
        f"{used:.0f} of 2 nodes ran the timed maps."
    )


def _value(rows: list[dict], **match: Any) -> float:
    """The value of the one row whose fields (and config keys) match, else NaN."""
    for row in rows:
        if all((row[k] if k in row else row["config"].get(k)) == v for k, v in match.items()):
            return float(row["value"])
    return float("nan")


def _write_table(cfg: ScalingConfig, res: Results) -> None:
    """``scaling.md``: the measured table, the two-node sentence and the projection table."""
    rows = [r | {"config": json.loads(r["config"])} for r in res.rows]
    planned = int(sum(_value(rows, system="plan", metric="bake_maps", scene=s) for s in builtin_scenes()))
    space = int(sum(_value(rows, system="plan", metric="space_maps", scene=s) for s in builtin_scenes()))
    lines = [
        f"Measured on {cfg.scenes[0]} at {cfg.resolution}², {cfg.spp} spp + OIDN; single-threaded workers.",
        "",
        "| executor | workers | frames/s | maps/s | efficiency (frames) | no-op round trip [ms] "
        "| no-op batched [ms/job] |",
        "|---|---|---|---|---|---|---|",
    ]
    for ex in cfg.executors:
        for w in sorted(cfg.workers):
            frame = _value(rows, system=ex, metric="throughput", workers=w, kind="frame")
            maps = _value(rows, system=ex, metric="throughput", workers=w, kind="map")
            eff = 1.0 if w == 1 else _value(rows, system=ex, metric="efficiency", workers=w, kind="frame")
            trip = _value(rows, system=ex, metric="task_roundtrip", stat="median", workers=w)
            batched = _value(rows, system=ex, metric="task_overhead_batched", workers=w)
            lines.append(
                f"| {_label(ex, w)} | {w} | {frame:.3g} | {maps:.3g} | {eff:.2f} | {trip:.3g} | {batched:.3g} |"
            )
    two = _two_nodes(rows)
    shown = _projected_on(list(cfg.executors))
    lines += [
        *(["", two] if two else []),
        "",
        f"PROJECTION (not measured), {cfg.spp} spp + OIDN: {cfg.project_frames} frames x 5 scenes at "
        f"{cfg.project_resolution}²; baking each scene's {cfg.bake_frames}-frame fly-through ({planned} maps) and its "
        f"whole configuration space ({space} maps) at {cfg.bake_resolution}²; {ASSUMPTION}.",
        "",
        "| N workers | " + " | ".join(f"{PROJECTED[m]}, {ex} [h]" for ex in shown for m in PROJECTED) + " |",
        "|---|" + "---|" * len(PROJECTED) * len(shown),
    ]
    for n in cfg.project_workers:
        cells = [f"{_value(rows, system=ex, scene=ALL, metric=m, workers=n):.3g}" for ex in shown for m in PROJECTED]
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    res.output("scaling.md").write_text("\n".join(lines) + "\n")


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Left: measured throughput per executor and worker count. Middle: maps/s against Ray nodes (simulated
    on this machine) with the no-op round trip. Right: the projections (labelled so)."""
    from gicore.plotting import plt, save

    rows = read_rows(csv_path)
    executors = list(dict.fromkeys(r["system"] for r in rows if r["metric"] == "throughput"))
    workers = sorted({r["config"]["workers"] for r in rows if r["metric"] == "throughput"})
    fig, (left, middle, right) = plt.subplots(1, 3, figsize=(16, 4.2))
    bars = [(ex, kind) for ex in executors for kind in UNITS]
    width = 0.8 / max(1, len(bars))
    for i, (ex, kind) in enumerate(bars):
        values = [_value(rows, system=ex, metric="throughput", workers=w, kind=kind) for w in workers]
        left.bar(np.arange(len(workers)) + (i + 0.5) * width - 0.4, values, width, label=f"{ex}: {UNITS[kind]}")
    trips = ", ".join(
        f"{ex} {_value(rows, system=ex, metric='task_roundtrip', stat='median', workers=1):.2g} ms" for ex in executors
    )
    left.set_xticks(np.arange(len(workers)), [f"{w} worker{'s' * (w > 1)}" for w in workers])
    left.set_ylabel("items per second (measured)")
    left.set_title(f"Measured throughput; no-op round trip: {trips}", fontsize=9)
    left.legend(fontsize=7)
    left.grid(axis="y", alpha=0.3)
    nodes = sorted(
        r["config"]["workers"]
        for r in rows
        if (r["system"], r["metric"], r["config"].get("kind")) == (CLUSTER, "throughput", "map")
    )
    for ex in executors:
        points = [(w, _value(rows, system=ex, metric="throughput", workers=w, kind="map")) for w in workers]
        label = "Ray nodes of 1 CPU (simulated)" if ex == CLUSTER else f"{ex}: workers on one node"
        middle.plot(*zip(*points), "-" if ex == CLUSTER else ":", marker="o", label=label)
    if nodes:
        trips = [_value(rows, system=CLUSTER, metric="task_roundtrip", stat="median", workers=n) for n in nodes]
        middle.set_title(
            "maps/s vs Ray nodes; no-op round trip "
            + ", ".join(f"{t:.2g} ms ({n})" for n, t in zip(nodes, trips))
            + "\nsimulated nodes share this machine's cores",
            fontsize=9,
        )
    middle.set_xticks(workers)
    middle.set_xlabel("nodes (ray-cluster) or workers")
    middle.set_ylabel("maps per second (measured)")
    middle.set_ylim(bottom=0)
    middle.legend(fontsize=7)
    middle.grid(alpha=0.3)
    for ex, style in zip(_projected_on(executors), ("-", "--")):
        for metric, label in (
            ("dataset_wall", "paper data set"),
            ("bake_wall", "GI-tree bake, 5 scenes"),
            ("space_wall", "configuration spaces, 5 scenes"),
        ):
            points = sorted(
                (r["config"]["workers"], r["value"])
                for r in rows
                if (r["system"], r["metric"], r["scene"]) == (ex, metric, ALL)
            )
            if points:
                right.plot(*zip(*points), style, marker="o", label=f"{label} ({ex})")
    right.set_xscale("log")
    right.set_yscale("log")
    right.set_xlabel("workers (single-threaded)")
    right.set_ylabel("PROJECTED wall time [h]")
    right.set_title("PROJECTION from the measured 1-worker cost (linear scaling assumed)", fontsize=9)
    right.legend(fontsize=7)
    right.grid(alpha=0.3, which="both")
    return [save(fig, out_dir / "scaling.png")]


def readme_block(rows: Rows) -> list[Table]:
    """Measured throughput per executor and worker count, the two-node sentence; then the projections,
    labelled as such."""
    need(rows, "throughput")
    measured = pick(rows, "throughput")
    c = measured[0]["config"]
    executors = list(dict.fromkeys(r["system"] for r in measured))
    workers = sorted({r["config"]["workers"] for r in measured})
    lines = [
        f"Measured on {measured[0]['scene']} at {c.get('resolution')}², {c.get('spp')} spp + OIDN, single-threaded "
        "workers.",
        "",
        "| executor | workers | frames/s | maps/s | efficiency (frames, against 1 worker) "
        "| no-op task round trip ms (median) |",
        "|---|---|---|---|---|---|",
    ]
    for ex in executors:
        for w in workers:
            frames, maps = (
                _value(rows, system=ex, metric="throughput", workers=w, kind=kind) for kind in ("frame", "map")
            )
            efficiency = 1.0 if w == 1 else _value(rows, system=ex, metric="efficiency", workers=w, kind="frame")
            trip = _value(rows, system=ex, metric="task_roundtrip", stat="median", workers=w)
            lines.append(
                f"| {_label(ex, w)} | {w} | {cell(frames, '.3g')} | {cell(maps, '.3g')} | {cell(efficiency, '.2f')} "
                f"| {cell(trip, '.3g')} |"
            )
    two = _two_nodes(rows)
    if two:
        lines += ["", two]
    projected = [r for r in rows if r["stat"] == "projection" and r["scene"] == ALL]
    if projected:
        what = {r["metric"]: r["config"] for r in projected}
        shown = [m for m in PROJECTED if m in what]
        on = _projected_on(executors)
        lines += [
            "",
            "PROJECTED, not measured: wall hours on N workers ("
            + "; ".join(f"{PROJECTED[m]}: {what[m].get('items')} items at {what[m].get('resolution')}²" for m in shown)
            + f"; {projected[0]['config'].get('assumption')}).",
            "",
            "| N workers | " + " | ".join(f"{PROJECTED[m]}, {ex} [h]" for ex in on for m in shown) + " |",
            "|---" * (1 + len(on) * len(shown)) + "|",
        ]
        for n in sorted({r["config"]["workers"] for r in projected}):
            cells = [cell(_value(rows, system=ex, scene=ALL, metric=m, workers=n), ".3g") for ex in on for m in shown]
            lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return [Table("\n".join(lines))]


BENCH = Bench(
    "scaling",
    ScalingConfig,
    measure,
    plot,
    help="Render executor: frames/maps per second with 1 and 2 workers, local processes vs Ray vs Ray nodes (a cluster "
    "simulated on this machine), per-task overhead, and the projected wall time of the paper's data set, of GI-tree "
    "bakes and of whole configuration spaces on N workers.",
    readme=Block("Scaling", 110, readme_block),
)
