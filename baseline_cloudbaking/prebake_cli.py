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
from pathlib import Path
from typing import Annotated

import typer
from tqdm import tqdm

from baseline_cloudbaking.bake import SCENE_NAME, bake_map, encode_map, spec_sha
from baseline_cloudbaking.codecs import CODEC_NAMES
from baseline_cloudbaking.store import GITree, MapKey, StoreConflict, Tolerance, Viewpoint, ViewSet, light_cell
from gicore.camera import Camera
from gicore.cli import UserError, entry_point, writable_dir
from gicore.fileio import exclusive_run
from gicore.paths import camera_path, frame_seed, light_position
from gicore.scene import SceneSpec, SceneSpecError, load_scene

app = typer.Typer(add_completion=False, help=__doc__)

#: (frame, camera fields, light, render seed) of one map to bake.
Job = tuple[int, dict, tuple[float, float, float], int]
_worker: dict = {}


def _init_worker(spec_dict: dict, name: str, resolution: int, codec: str, spp: int, di: bool, threads: int) -> None:
    """Compile the scene for :func:`_bake_job` in this process."""
    import drjit

    from gicore.render import Renderer  # before any Dr.Jit call: it locates libLLVM

    drjit.set_thread_count(threads)
    spec = SceneSpec.from_dict(spec_dict)
    _worker.update(renderer=Renderer(spec, resolution), spec=spec, name=name, codec=codec, spp=spp, di=di)


def _init_pool_worker(*args) -> None:
    """A pool worker: Ctrl-C is the parent's to handle (it cancels the pool and exits resumable)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _init_worker(*args)


def _bake_job(job: Job) -> tuple[int, bytes]:
    frame, camera, light, seed = job
    w = _worker
    baked = bake_map(w["renderer"], Camera.from_dict(camera), light, w["spp"], seed, w["di"])
    return frame, encode_map(baked, w["name"], w["codec"], w["spp"], light if w["spec"].light.moves else None)


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
    frames: Annotated[int, typer.Option(min=1, max=100_000, help="frames of the fly-through (paper: 1500)")] = 1500,
    codec: Annotated[str, typer.Option(help=f"GI-map codec: {', '.join(CODEC_NAMES)}")] = "jpeg",
    resolution: Annotated[int, typer.Option(min=16, max=2048, help="square map resolution")] = 256,
    spp: Annotated[int, typer.Option(min=1, max=4096, help="path-tracing samples per pixel (then OIDN)")] = 64,
    di: Annotated[bool, typer.Option(help="also store the GI view's DI (needed by the residual composition)")] = False,
    fov: Annotated[float | None, typer.Option(min=1.0, max=170.0, help="GI-camera FOV in degrees (default: the scene's, 90)")] = None,
    tolerance_p: Annotated[float, typer.Option(min=0.0, help="Δp: eye distance a map serves, scene units")] = Tolerance.position,
    tolerance_deg: Annotated[float, typer.Option(min=0.0, max=180.0, help="Δθ: view angle a map serves, degrees")] = Tolerance.angle_deg,
    light_cell_size: Annotated[float, typer.Option("--light-cell", min=1e-6, help="light-cell side for a moving light, scene units")] = 0.25,
    seed: Annotated[int, typer.Option(help="camera-path seed (as gicore-dataset) and render-noise seed")] = 0,
    workers: Annotated[int, typer.Option(min=1, max=64, help="rendering processes")] = 1,
) -> None:
    """Bake the maps of SCENE's fly-through into --store (resumable)."""
    if codec not in CODEC_NAMES:
        raise UserError(f"--codec {codec!r} is unknown", f"choose one of {', '.join(CODEC_NAMES)}")
    name, spec = _scene(scene)
    writable_dir(store, name="--store")
    t0 = time.perf_counter()
    with ExitStack() as stack:
        try:
            stack.enter_context(exclusive_run(store / ".prebake" / name))
        except UserError:
            raise UserError(f"another cloudbaking-prebake is baking {name} into {store}", "wait for it to finish, then rerun to check") from None
        _bake(store, name, spec, frames, codec, resolution, spp, di, fov, Tolerance(tolerance_p, tolerance_deg), light_cell_size, seed, workers, t0)


def _bake(store_dir: Path, name: str, spec: SceneSpec, frames: int, codec: str, resolution: int, spp: int, di: bool, fov: float | None,
          tol: Tolerance, light_cell_size: float, seed: int, workers: int, t0: float) -> None:  # fmt: skip
    cameras = camera_path(spec, frames, seed=seed, fov=fov, resolution=resolution)
    lights = [light_position(spec, i) for i in range(frames)]
    cell_size = light_cell_size if spec.light.moves else None
    with GITree(store_dir, tolerance=tol) as tree:
        try:
            tree.register_scene(name, spec_sha(spec), cell_size)
        except StoreConflict as exc:
            raise UserError(str(exc), "use another --store, or the --light-cell and spec it was baked with") from None
        keys = [MapKey(name, light_cell(light, cell_size), resolution, cam.fov, codec, spp, di) for cam, light in zip(cameras, lights, strict=True)]
        views = [Viewpoint.look_at(cam.origin, cam.target) for cam in cameras]
        todo = plan(tree, keys, views)
        jobs: list[Job] = [(i, cameras[i].to_dict(), lights[i], frame_seed(seed, f"prebake/{name}", i)) for i in todo]
        typer.echo(f"{name}: {frames} frames; {len(jobs)} maps to bake", err=True)

        def insert(frame: int, payload: bytes) -> None:
            tree.insert(keys[frame], views[frame], payload)

        init = (spec.to_dict(), name, resolution, codec, spp, di)
        bar = tqdm(total=len(jobs), desc=name, unit="map", disable=not jobs)
        if workers == 1 or len(jobs) <= 1:  # no pool: cheaper, and Mitsuba already uses every core
            _init_worker(*init, os.cpu_count() or 1)
            for job in jobs:
                insert(*_bake_job(job))
                bar.update()
        else:
            threads = max(1, (os.cpu_count() or 1) // workers)
            # spawn, not fork: a forked worker inherits OIDN's thread pool state and can deadlock in it.
            ctx = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_pool_worker, initargs=(*init, threads)) as pool:
                futures = [pool.submit(_bake_job, job) for job in jobs]
                try:
                    for future in as_completed(futures):
                        insert(*future.result())
                        bar.update()
                except KeyboardInterrupt:
                    pool.shutdown(wait=False, cancel_futures=True)
                    raise
        bar.close()
        usage = [u for u in tree.stats()["by_scene_codec"] if u["scene"] == name and u["codec"] == codec]
        mib = usage[0]["bytes"] / 2**20 if usage else 0.0
        served = sum(tree.find(key, view) is not None for key, view in zip(keys, views, strict=True))
        typer.echo(
            f"{name}: {served}/{frames} frames served by the store; {len(jobs)} maps baked now; {mib:.1f} MiB of {codec} maps "
            f"for {name} in {store_dir} ({time.perf_counter() - t0:.1f} s)"
        )


main = entry_point(app, resume="rerun the same command; finished maps are kept and only the rest is baked")
