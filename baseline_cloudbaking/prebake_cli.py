"""`cloudbaking-prebake`: bake the GI maps of a scene's fly-through into a GI tree, ahead of any client.

    cloudbaking-prebake lung_plane --store gi_store --frames 1500 --codec jpeg --resolution 256 --workers 2

The fly-through is the scene's camera path (``gicore.paths.camera_path`` with the GI-camera FOV) with
its light schedule. Walking it in order, a frame needs a new map unless the store, or a map planned
earlier in this run, serves it within the tolerance (same light cell): the same rule the server's
lookups apply, so a client flying the path afterwards only hits. Maps are rendered by a pool of spawned
worker processes (one compiled scene each) and inserted as they finish; a rerun (after Ctrl-C, a crash
or kill -9) plans again from what the store holds and bakes only the rest.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import typer
from tqdm import tqdm

from baseline_cloudbaking.bake import SCENE_NAME, bake_map, encode_map, fly_through, spec_sha
from baseline_cloudbaking.codecs import CODEC_NAMES
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree, MapKey, StoreConflict, Tolerance, Viewpoint, ViewSet
from gicore.camera import Camera
from gicore.cli import UserError, entry_point, writable_dir
from gicore.fileio import exclusive_run
from gicore.paths import frame_seed
from gicore.scene import SceneSpec, SceneSpecError, load_scene

app = typer.Typer(add_completion=False, help=__doc__)


@dataclass(frozen=True)
class PrebakeConfig:
    """What a prebake bakes for one scene."""

    #: Frames of the fly-through (paper: 1500).
    frames: int = 1500
    #: GI-map codec (:data:`baseline_cloudbaking.codecs.CODEC_NAMES`).
    codec: str = "jpeg"
    #: Square map resolution.
    resolution: int = 256
    #: Path-tracing samples per pixel (then OIDN).
    spp: int = 64
    #: Also store the GI view's DI (the residual composition needs it).
    di: bool = False
    #: GI-camera FOV in degrees; None: the scene's (90°).
    fov: float | None = None
    #: Δp / Δθ within which a stored map serves a frame.
    tolerance: Tolerance = field(default_factory=Tolerance)
    #: Light-cell side for a moving light, scene units.
    light_cell: float = DEFAULT_LIGHT_CELL
    #: Camera-path seed (as gicore-dataset) and render-noise seed.
    seed: int = 0
    #: Rendering processes.
    workers: int = 1


@dataclass(frozen=True)
class PrebakeResult:
    """What a prebake did: frames of the path the store now serves, maps baked by this run, and the
    scene's stored bytes for the codec."""

    frames: int
    served: int
    baked: int
    bytes: int


#: (frame, camera fields, light, render seed) of one map to bake.
Job = tuple[int, dict, tuple[float, float, float], int]
_worker: dict = {}


def _init_worker(spec_dict: dict, name: str, cfg: PrebakeConfig, threads: int) -> None:
    """Compile the scene for :func:`_bake_job` in this process."""
    import drjit

    from gicore.render import Renderer  # before any Dr.Jit call: it locates libLLVM

    drjit.set_thread_count(threads)
    spec = SceneSpec.from_dict(spec_dict)
    _worker.update(renderer=Renderer(spec, cfg.resolution), spec=spec, name=name, cfg=cfg)


def _init_pool_worker(*args) -> None:
    """A pool worker: Ctrl-C is the parent's to handle (it cancels the pool and exits resumable)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _init_worker(*args)


def _bake_job(job: Job) -> tuple[int, bytes]:
    frame, camera, light, seed = job
    cfg: PrebakeConfig = _worker["cfg"]
    baked = bake_map(_worker["renderer"], Camera.from_dict(camera), light, cfg.spp, seed, cfg.di)
    return frame, encode_map(baked, _worker["name"], cfg.codec, cfg.spp, light if _worker["spec"].light.moves else None)


def plan(store: GITree, keys: list[MapKey], views: list[Viewpoint]) -> list[int]:
    """Frames of a path (``keys``/``views`` per frame) that need a new map: neither the store nor a map
    planned for an earlier frame serves them."""
    planned: dict = {}
    todo = []
    for i, (key, view) in enumerate(zip(keys, views, strict=True)):
        if store.find(key, view) is not None:
            continue
        cell_views = planned.setdefault(key.light_cell, ViewSet())
        if cell_views.nearest(view, store.tolerance) is None:
            cell_views.add(view)
            todo.append(i)
    return todo


def prebake_scene(store_dir: Path, name: str, spec: SceneSpec, cfg: PrebakeConfig, progress: bool = True) -> PrebakeResult:
    """Bake what ``store_dir`` lacks of ``spec``'s fly-through (stored as scene ``name``)."""
    path = fly_through(spec, cfg.frames, cfg.resolution, cfg.light_cell, cfg.seed, cfg.fov)
    with GITree(store_dir, tolerance=cfg.tolerance) as tree:
        try:
            tree.register_scene(name, spec_sha(spec), cfg.light_cell if spec.light.moves else None)
        except StoreConflict as exc:
            raise UserError(str(exc), "use another --store, or the --light-cell and spec it was baked with") from None
        keys = [MapKey(name, f.cell, cfg.resolution, f.camera.fov, cfg.codec, cfg.spp, cfg.di) for f in path]
        views = [f.view for f in path]
        jobs: list[Job] = [(i, path[i].camera.to_dict(), path[i].light, frame_seed(cfg.seed, f"prebake/{name}", i)) for i in plan(tree, keys, views)]
        if progress:
            typer.echo(f"{name}: {cfg.frames} frames; {len(jobs)} maps to bake", err=True)
        bar = tqdm(total=len(jobs), desc=name, unit="map", disable=not (progress and jobs))
        if cfg.workers == 1 or len(jobs) <= 1:  # no pool: cheaper, and Mitsuba already uses every core
            _init_worker(spec.to_dict(), name, cfg, os.cpu_count() or 1)
            for job in jobs:
                frame, payload = _bake_job(job)
                tree.insert(keys[frame], views[frame], payload)
                bar.update()
        else:
            threads = max(1, (os.cpu_count() or 1) // cfg.workers)
            # spawn, not fork: a forked worker inherits OIDN's thread pool state and can deadlock in it.
            ctx = multiprocessing.get_context("spawn")
            init = (spec.to_dict(), name, cfg, threads)
            with ProcessPoolExecutor(cfg.workers, mp_context=ctx, initializer=_init_pool_worker, initargs=init) as pool:
                futures = [pool.submit(_bake_job, job) for job in jobs]
                try:
                    for future in as_completed(futures):
                        frame, payload = future.result()
                        tree.insert(keys[frame], views[frame], payload)
                        bar.update()
                except KeyboardInterrupt:
                    pool.shutdown(wait=False, cancel_futures=True)
                    raise
        bar.close()
        usage = [u["bytes"] for u in tree.stats()["by_scene_codec"] if (u["scene"], u["codec"]) == (name, cfg.codec)]
        served = sum(tree.find(key, view) is not None for key, view in zip(keys, views, strict=True))
        return PrebakeResult(cfg.frames, served, len(jobs), sum(usage))


def _scene(scene: str) -> tuple[str, SceneSpec]:
    """(store name, spec) of a built-in scene name or a spec file (named by its stem)."""
    name = Path(scene).stem
    if not SCENE_NAME.match(name):
        raise UserError(f"scene name {name!r} (from {scene!r}) is malformed", "name spec files with a letter or '_', then letters, digits or '_'")
    try:
        return name, load_scene(scene)
    except UserError:  # SceneSpecError is one: it names the file and the fields
        raise
    except (FileNotFoundError, SceneSpecError) as exc:
        raise UserError(str(exc), "give a built-in scene name or a valid .toml/.json spec file") from None


@app.command()
def prebake(
    scene: Annotated[str, typer.Argument(help="built-in scene name or spec file (.toml/.json); the file stem names it in the store")],
    store: Annotated[Path, typer.Option(help="GI-tree folder (created if missing; shared with cloudbaking-server --store)")],
    frames: Annotated[int, typer.Option(min=1, max=100_000, help="frames of the fly-through (paper: 1500)")] = PrebakeConfig.frames,
    codec: Annotated[str, typer.Option(help=f"GI-map codec: {', '.join(CODEC_NAMES)}")] = PrebakeConfig.codec,
    resolution: Annotated[int, typer.Option(min=16, max=2048, help="square map resolution")] = PrebakeConfig.resolution,
    spp: Annotated[int, typer.Option(min=1, max=4096, help="path-tracing samples per pixel (then OIDN)")] = PrebakeConfig.spp,
    di: Annotated[bool, typer.Option(help="also store the GI view's DI (needed by the residual composition)")] = PrebakeConfig.di,
    fov: Annotated[float | None, typer.Option(min=1.0, max=170.0, help="GI-camera FOV in degrees (default: the scene's, 90)")] = None,
    tolerance_p: Annotated[float, typer.Option(min=0.0, help="Δp: eye distance a map serves, scene units")] = Tolerance.position,
    tolerance_deg: Annotated[float, typer.Option(min=0.0, max=180.0, help="Δθ: view angle a map serves, degrees")] = Tolerance.angle_deg,
    light_cell: Annotated[float, typer.Option(min=1e-6, help="light-cell side for a moving light, scene units")] = DEFAULT_LIGHT_CELL,
    seed: Annotated[int, typer.Option(help="camera-path seed (as gicore-dataset) and render-noise seed")] = PrebakeConfig.seed,
    workers: Annotated[int, typer.Option(min=1, max=64, help="rendering processes")] = PrebakeConfig.workers,
) -> None:
    """Bake the maps of SCENE's fly-through into --store (resumable)."""
    if codec not in CODEC_NAMES:
        raise UserError(f"--codec {codec!r} is unknown", f"choose one of {', '.join(CODEC_NAMES)}")
    name, spec = _scene(scene)
    writable_dir(store, name="--store")
    cfg = PrebakeConfig(frames, codec, resolution, spp, di, fov, Tolerance(tolerance_p, tolerance_deg), light_cell, seed, workers)
    t0 = time.perf_counter()
    with ExitStack() as stack:
        try:
            stack.enter_context(exclusive_run(store / ".prebake" / name))
        except UserError:
            raise UserError(f"another cloudbaking-prebake is baking {name} into {store}", "wait for it to finish, then rerun to check") from None
        result = prebake_scene(store, name, spec, cfg)
    typer.echo(
        f"{name}: {result.served}/{result.frames} frames served by the store; {result.baked} maps baked now; "
        f"{result.bytes / 2**20:.1f} MiB of {codec} maps for {name} in {store} ({time.perf_counter() - t0:.1f} s)"
    )


main = entry_point(app, resume="rerun the same command; finished maps are kept and only the rest is baked")
