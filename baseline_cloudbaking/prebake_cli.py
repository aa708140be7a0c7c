"""`cloudbaking-prebake`: bake the GI maps of a scene's fly-through into a GI tree, ahead of any client.

    cloudbaking-prebake lung_plane --store gi_store --frames 1500 --codec jpeg --resolution 256 --workers 2

The fly-through is the scene's camera path (``gicore.paths.camera_path`` with the GI-camera FOV) with
its light schedule. Walking it in order, a frame needs a new map unless the store, or a map planned
earlier in this run, serves it within the tolerance (same light cell): the same rule the server's
lookups apply, so a client flying the path afterwards only hits. Maps are rendered by the render
executor (``gicore.executor``: this process, ``--workers`` local processes, or Ray tasks with ``--ray
auto|HOST:PORT`` for a bake farm; one compiled scene per worker) and inserted by this process as they
arrive; a rerun (after Ctrl-C, a crash or kill -9) plans again from what the store holds and bakes only
the rest.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import typer
from tqdm import tqdm

from baseline_cloudbaking.bake import SCENE_NAME, PathFrame, bake_map, encode_map, fly_through, spec_sha
from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree, MapKey, StoreConflict, Tolerance, Viewpoint, ViewSet
from gicore.camera import Camera
from gicore.cli import UserError, entry_point, writable_dir
from gicore.executor import RAY_HELP, WORKERS_HELP, Executor, InProcess, Task, open_executor
from gicore.fileio import FolderHeld, exclusive_run
from gicore.options import (
    FOV_DEGREES,
    FRAMES,
    RESOLUTION,
    SEED,
    SPP,
    THREADS,
    build_config,
    config_command,
    config_options,
    extra,
)
from gicore.paths import frame_seed
from gicore.scene import SceneSpec, SceneSpecError, load_scene

if TYPE_CHECKING:
    from gicore.render import Renderer

app = typer.Typer(add_completion=False, help=__doc__)


@dataclass(frozen=True)
class PrebakeConfig:
    """What a prebake bakes for one scene. The command's options are derived from these fields
    (:mod:`gicore.options`); ``tolerance`` comes from :class:`ToleranceOptions`."""

    #: Frames of the fly-through (paper: 1500).
    frames: int = field(default=1500, metadata=FRAMES)
    #: GI-map codec.
    codec: Literal[CODEC_NAMES] = DEFAULT_CODEC  # type: ignore[valid-type]
    #: Square map resolution.
    resolution: int = field(default=256, metadata=RESOLUTION)
    #: Path-tracing samples per pixel (then OIDN).
    spp: int = field(default=64, metadata=SPP)
    #: Also store the GI view's DI (the residual composition needs it).
    di: bool = False
    #: GI-camera FOV in degrees; absent: the scene's (90).
    fov: float | None = field(default=None, metadata=FOV_DEGREES)
    #: Δp / Δθ within which a stored map serves a frame.
    tolerance: Tolerance = field(default_factory=Tolerance)
    #: Light-cell side for a moving light, scene units.
    light_cell: float = field(default=DEFAULT_LIGHT_CELL, metadata={"min": 1e-6, "max": 1e6})
    #: Camera-path seed (as gicore-dataset) and render-noise seed.
    seed: int = field(default=0, metadata=SEED)


@dataclass(frozen=True)
class ToleranceOptions:
    """The command-line form of :class:`~baseline_cloudbaking.store.Tolerance` (its defaults)."""

    #: Δp: eye distance a stored map serves, scene units.
    tolerance_p: float = field(default=Tolerance.position, metadata={"min": 0.0, "max": 1e6})
    #: Δθ: view angle a stored map serves, degrees.
    tolerance_deg: float = field(default=Tolerance.angle_deg, metadata={"min": 0.0, "max": 180.0})

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_p, self.tolerance_deg)


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
#: A worker's state: the compiled scene, its spec, its store name and the bake settings.
Baker = tuple["Renderer", SceneSpec, str, PrebakeConfig]


def _build_baker(spec_dict: dict, name: str, cfg: PrebakeConfig) -> Baker:
    from gicore.render import Renderer

    spec = SceneSpec.from_dict(spec_dict)
    return Renderer(spec, cfg.resolution), spec, name, cfg


def _bake_job(baker: Baker, job: Job) -> bytes:
    renderer, spec, name, cfg = baker
    _, camera, light, seed = job
    baked = bake_map(renderer, Camera.from_dict(camera), light, cfg.spp, seed, cfg.di)
    return encode_map(baked, name, cfg.codec, cfg.spp, light if spec.light.moves else None)


def bake_task(spec: SceneSpec, name: str, cfg: PrebakeConfig) -> Task:
    """The render task of a prebake (a compiled scene per worker; a job's result is the map's stored payload)."""
    return Task(_build_baker, (spec.to_dict(), name, cfg), _bake_job)


def bake_jobs(path: list[PathFrame], frames: Iterable[int], name: str, seed: int) -> list[Job]:
    """The jobs that bake ``frames`` of the fly-through ``path`` of scene ``name`` (render seeds from ``seed``)."""
    return [(i, path[i].camera.to_dict(), path[i].light, frame_seed(seed, f"prebake/{name}", i)) for i in frames]


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


def prebake_scene(
    store_dir: Path,
    name: str,
    spec: SceneSpec,
    cfg: PrebakeConfig,
    executor: Executor | None = None,
    progress: bool = True,
) -> PrebakeResult:
    """Bake what ``store_dir`` lacks of ``spec``'s fly-through (stored as scene ``name``) on ``executor``
    (default: this process)."""
    path = fly_through(spec, cfg.frames, cfg.resolution, cfg.light_cell, cfg.seed, cfg.fov)
    with GITree(store_dir, tolerance=cfg.tolerance) as tree:
        try:
            tree.register_scene(name, spec_sha(spec), cfg.light_cell if spec.light.moves else None)
        except StoreConflict as exc:
            raise UserError(str(exc), "use another --store, or the --light-cell and spec it was baked with") from None
        keys = [MapKey(name, f.cell, cfg.resolution, f.camera.fov, cfg.codec, cfg.spp, cfg.di) for f in path]
        views = [f.view for f in path]
        jobs = bake_jobs(path, plan(tree, keys, views), name, cfg.seed)
        if progress:
            typer.echo(f"{name}: {cfg.frames} frames; {len(jobs)} maps to bake", err=True)
        with tqdm(total=len(jobs), desc=name, unit="map", disable=not (progress and jobs)) as bar:

            def receive(job: Job, payload: bytes) -> None:
                tree.insert(keys[job[0]], views[job[0]], payload)
                bar.update()

            (executor or InProcess()).run(bake_task(spec, name, cfg), jobs, receive)
        usage = [u["bytes"] for u in tree.stats()["by_scene_codec"] if (u["scene"], u["codec"]) == (name, cfg.codec)]
        served = sum(tree.find(key, view) is not None for key, view in zip(keys, views, strict=True))
        return PrebakeResult(cfg.frames, served, len(jobs), sum(usage))


def _scene(scene: str) -> tuple[str, SceneSpec]:
    """(store name, spec) of a built-in scene name or a spec file (named by its stem)."""
    name = Path(scene).stem
    if not SCENE_NAME.match(name):
        raise UserError(
            f"scene name {name!r} (from {scene!r}) is malformed",
            "name spec files with a letter or '_', then letters, digits or '_'",
        )
    try:
        return name, load_scene(scene)
    except UserError:  # SceneSpecError is one: it names the file and the fields
        raise
    except (FileNotFoundError, SceneSpecError) as exc:
        raise UserError(str(exc), "give a built-in scene name or a valid .toml/.json spec file") from None


def prebake(
    given: dict[str, Any],
    *,
    scene: str,
    store: Path,
    tolerance_p: float | None,
    tolerance_deg: float | None,
    workers: int | None,
    ray: str | None,
) -> None:
    """Bake the maps of SCENE's fly-through into --store (resumable)."""
    given_tolerance = {
        k: v for k, v in (("tolerance_p", tolerance_p), ("tolerance_deg", tolerance_deg)) if v is not None
    }
    tolerance = build_config(ToleranceOptions, given_tolerance).tolerance
    cfg = build_config(PrebakeConfig, given, PrebakeConfig(tolerance=tolerance))
    name, spec = _scene(scene)
    writable_dir(store, name="--store")
    t0 = time.perf_counter()
    with ExitStack() as stack:
        try:
            stack.enter_context(exclusive_run(store / ".prebake" / name))
        except FolderHeld as exc:
            by = "" if exc.holder is None else f" (process {exc.holder})"
            raise UserError(
                f"another cloudbaking-prebake{by} is baking {name} into {store}",
                "wait for it to finish, then rerun to check",
            ) from None
        result = prebake_scene(store, name, spec, cfg, stack.enter_context(open_executor(workers, ray)))
    typer.echo(
        f"{name}: {result.served}/{result.frames} frames served by the store; {result.baked} maps baked now; "
        f"{result.bytes / 2**20:.1f} MiB of {cfg.codec} maps for {name} in {store} ({time.perf_counter() - t0:.1f} s)"
    )


SCENE_HELP = "built-in scene name or spec file (.toml/.json); the file stem names it in the store"
STORE_HELP = "GI-tree folder (created if missing; shared with cloudbaking-server --store)"
config_command(
    app,
    PrebakeConfig,
    prebake,
    exclude=("tolerance",),
    extras=[
        extra("scene", Annotated[str, typer.Argument(help=SCENE_HELP)]),
        extra("store", Annotated[Path, typer.Option("--store", help=STORE_HELP)]),
        *config_options(ToleranceOptions),
        extra(
            "workers",
            Annotated[int | None, typer.Option("--workers", min=1, max=THREADS["max"], help=WORKERS_HELP)],
            None,
        ),
        extra("ray", Annotated[str | None, typer.Option("--ray", help=RAY_HELP)], None),
    ],
)


main = entry_point(app, resume="rerun the same command; finished maps are kept and only the rest is baked")
