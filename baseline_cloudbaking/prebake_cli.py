"""`cloudbaking-prebake`: bake the GI maps of a scene's fly-through, or of its whole configuration space,
into a GI tree, ahead of any client.

    cloudbaking-prebake lung_plane --store gi_store --frames 1500 --codec jpeg --resolution 256 --workers 2
    cloudbaking-prebake lung_cornell --store gi_store --space all --executor ray --ray-address HEAD:6379

A frame of the fly-through needs a new map unless the store, or a map planned earlier in the run, serves it by
the server's own lookup rule, so a client flying the path afterwards only hits. ``--space all`` bakes every
view of the camera's envelope at the tolerance times every light cell, in chunks of :data:`SPACE_CHUNK` maps.
Maps are rendered by the render executor and inserted by this process alone; a rerun (after Ctrl-C, a crash
or kill -9) bakes only what is missing, and workers never outlive the driver. docs/architecture.md, GI tree.
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

from baseline_cloudbaking.bake import (
    SCENE_NAME,
    ConfigurationSpace,
    PathFrame,
    bake_map,
    configuration_space,
    encode_map,
    fly_through,
    gi_camera,
    spec_sha,
)
from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC
from baseline_cloudbaking.store import DEFAULT_LIGHT_CELL, GITree, store_folder
from baseline_cloudbaking.store_errors import StoreConflict
from baseline_cloudbaking.viewpoints import CellViews, MapKey, Tolerance, Viewpoint, simulate_fill
from gicore import option_groups
from gicore.camera import Camera
from gicore.error_policy import UserError, entry_point
from gicore.executor import Executor, ExecutorOptions, InProcess, RayExecutor, Task
from gicore.fileio import FolderHeld, exclusive_run, made_folder
from gicore.options import (
    FOV_DEGREES,
    FRAMES,
    build_config,
    build_options,
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
    resolution: int = option_groups.resolution(note="of the maps")
    spp: int = option_groups.spp(note="then OIDN")
    #: Also store the GI view's DI (the residual composition needs it).
    di: bool = False
    #: GI-camera FOV in degrees; absent: the scene's (90).
    fov: float | None = field(default=None, metadata=FOV_DEGREES)
    #: Δp / Δθ within which a stored map serves a frame.
    tolerance: Tolerance = field(default_factory=Tolerance)
    #: Light-cell side for a moving light, scene units.
    light_cell: float = field(default=DEFAULT_LIGHT_CELL, metadata={"min": 1e-6, "max": 1e6})
    seed: int = option_groups.seed(note="the camera path, as gicore-dataset's, and the render noise")
    #: What to bake: 'fly-through' (the maps the fly-through's --frames frames need) or 'all' (the scene's whole
    #: configuration space: views covering the camera's envelope at the tolerance x every light cell).
    space: Literal["fly-through", "all"] = "fly-through"


@dataclass(frozen=True)
class ToleranceOptions:
    """The command-line form of :class:`~baseline_cloudbaking.viewpoints.Tolerance` (its defaults)."""

    #: Δp: eye distance a stored map serves, scene units.
    tolerance_p: float = field(default=Tolerance.position, metadata={"min": 0.0, "max": 1e6})
    #: Δθ: view angle a stored map serves, degrees.
    tolerance_deg: float = field(default=Tolerance.angle_deg, metadata={"min": 0.0, "max": 180.0})

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_p, self.tolerance_deg)


@dataclass(frozen=True)
class PrebakeResult:
    """What a prebake did: ``frames`` of the path (with ``--space all``: configurations of the space) and
    how many of them the store now serves, maps baked by this run, and the scene's stored bytes for the codec."""

    frames: int
    served: int
    baked: int
    bytes: int


#: Configurations of a space planned and baked per executor run (memory stays bounded for millions of maps).
SPACE_CHUNK = 4096
#: A configuration is baked when the store holds a map at its view, to rounding: directions normalised by another
#: formula (numpy's norm, or plain floats) differ in the last bit, ~1e-14 degrees.
EXACT = Tolerance(1e-9, 1e-6)
#: Up vector of the space's GI cameras (the fly-through's cameras use the same).
UP = (0.0, 1.0, 0.0)

#: (frame or view index, camera fields, light, render seed) of one map to bake.
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
    planned = CellViews()
    todo = []
    for i, (key, view) in enumerate(zip(keys, views, strict=True)):
        if store.find(key, view) is None and planned.find(view, key.light_cell, store.tolerance) is None:
            planned.add(view, key.light_cell, i)
            todo.append(i)
    return todo


def space_of(spec: SceneSpec, cfg: PrebakeConfig) -> ConfigurationSpace:
    """The configuration space ``cfg`` bakes (a UserError when its tolerance covers no grid)."""
    try:
        return configuration_space(spec, cfg.tolerance, cfg.light_cell)
    except ValueError as exc:
        raise UserError(str(exc), "give a larger --tolerance-p / --tolerance-deg") from None


def maps_to_bake(spec: SceneSpec, cfg: PrebakeConfig) -> int:
    """Maps a prebake of ``spec`` with ``cfg`` bakes into an empty store, counted without rendering: the whole
    configuration space, or the fly-through's frames that no map planned for an earlier frame serves (:func:`plan`'s
    rule)."""
    if cfg.space == "all":
        return space_of(spec, cfg).size
    path = fly_through(spec, cfg.frames, cfg.resolution, cfg.light_cell, cfg.seed, cfg.fov)
    return len(set(simulate_fill([f.view for f in path], [f.cell for f in path], cfg.tolerance)))


def prebake_scene(
    store_dir: Path,
    name: str,
    spec: SceneSpec,
    cfg: PrebakeConfig,
    executor: Executor | None = None,
    progress: bool = True,
) -> PrebakeResult:
    """Bake what ``store_dir`` lacks of ``spec``'s fly-through, or with ``cfg.space == "all"`` of its
    configuration space (stored as scene ``name``), on ``executor`` (default: this process)."""
    with GITree(store_dir, tolerance=cfg.tolerance) as tree:
        try:
            tree.register_scene(name, spec_sha(spec), cfg.light_cell if spec.light.moves else None)
        except StoreConflict as exc:
            raise UserError(str(exc), "use another --store, or the --light-cell and spec it was baked with") from None
        bake = _bake_space if cfg.space == "all" else _bake_fly_through
        total, served, baked = bake(tree, name, spec, cfg, executor or InProcess(), progress)
        usage = [u["bytes"] for u in tree.stats()["by_scene_codec"] if (u["scene"], u["codec"]) == (name, cfg.codec)]
        return PrebakeResult(total, served, baked, sum(usage))


def _bake_fly_through(
    tree: GITree, name: str, spec: SceneSpec, cfg: PrebakeConfig, executor: Executor, progress: bool
) -> tuple[int, int, int]:
    """(frames, frames served, maps baked) of baking what the fly-through needs."""
    path = fly_through(spec, cfg.frames, cfg.resolution, cfg.light_cell, cfg.seed, cfg.fov)
    keys = [MapKey(name, f.cell, cfg.resolution, f.camera.fov, cfg.codec, cfg.spp, cfg.di) for f in path]
    views = [f.view for f in path]
    jobs = bake_jobs(path, plan(tree, keys, views), name, cfg.seed)
    if progress:
        typer.echo(f"{name}: {cfg.frames} frames; {len(jobs)} maps to bake", err=True)
    with tqdm(total=len(jobs), desc=name, unit="map", disable=not (progress and jobs)) as bar:

        def receive(job: Job, payload: bytes) -> None:
            tree.insert(keys[job[0]], views[job[0]], payload)
            bar.update()

        executor.run(bake_task(spec, name, cfg), jobs, receive)
    served = sum(tree.find(key, view) is not None for key, view in zip(keys, views, strict=True))
    return cfg.frames, served, len(jobs)


def _bake_space(
    tree: GITree, name: str, spec: SceneSpec, cfg: PrebakeConfig, executor: Executor, progress: bool
) -> tuple[int, int, int]:
    """(configurations, configurations stored, maps baked) of baking the configuration space."""
    space = space_of(spec, cfg)
    views = space.views()
    fov = spec.camera.gi_fov if cfg.fov is None else cfg.fov
    task = bake_task(spec, name, cfg)
    if progress:
        typer.echo(
            f"{name}: configuration space of {space.size} maps ({len(views)} views x {len(space.lights)} light "
            f"states; grid {'x'.join(map(str, space.grid))}, every view within {space.cover:.3g} of one)",
            err=True,
        )
    stored = baked = 0
    with tqdm(total=space.size, desc=name, unit="map", disable=not progress) as bar:
        for cell, light in space.lights:
            key = MapKey(name, cell, cfg.resolution, fov, cfg.codec, cfg.spp, cfg.di)
            for start in range(0, len(views), SPACE_CHUNK):
                chunk = range(start, min(start + SPACE_CHUNK, len(views)))
                todo = [i for i in chunk if tree.find(key, views[i], EXACT) is None]
                stored += len(chunk) - len(todo)
                bar.update(len(chunk) - len(todo))
                jobs = [
                    (
                        i,
                        gi_camera(spec, tuple(space.eyes[i]), space.target, UP, fov, cfg.resolution).to_dict(),
                        light,
                        frame_seed(cfg.seed, f"prebake/{name}/space/{cell}", i),
                    )
                    for i in todo
                ]

                def receive(job: Job, payload: bytes, key: MapKey = key) -> None:
                    nonlocal stored
                    stored += tree.insert(key, views[job[0]], payload) is not None
                    bar.update()

                executor.run(task, jobs, receive)
                baked += len(jobs)
    return space.size, stored, baked


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
    store: str,
    tolerance_p: float | None,
    tolerance_deg: float | None,
    executor: str | None,
    ray_address: str | None,
    workers: int | None,
) -> None:
    """Bake the maps of SCENE's fly-through, or of its whole configuration space, into --store (resumable)."""
    tolerance = build_options(ToleranceOptions, tolerance_p=tolerance_p, tolerance_deg=tolerance_deg).tolerance
    cfg = build_config(PrebakeConfig, given, PrebakeConfig(tolerance=tolerance))
    run_on = build_options(ExecutorOptions, executor=executor, ray_address=ray_address, workers=workers)
    name, spec = _scene(scene)
    if cfg.space == "all":
        space_of(spec, cfg)  # refused before the store or a Ray instance is touched
    t0 = time.perf_counter()
    with ExitStack() as stack:
        # a run refused before it stores a map (no Ray cluster answers, say) leaves no folder
        folder = stack.enter_context(made_folder(store_folder(store), name="--store"))
        try:
            stack.enter_context(exclusive_run(folder / ".prebake" / name))
        except FolderHeld as exc:
            by = "" if exc.holder is None else f" (process {exc.holder})"
            raise UserError(
                f"another cloudbaking-prebake{by} is baking {name} into {store}",
                "wait for it to finish, then rerun to check",
            ) from None
        pool = stack.enter_context(run_on.open())
        result = prebake_scene(folder, name, spec, cfg, pool)
    what = "configurations of the space stored" if cfg.space == "all" else "frames served by the store"
    typer.echo(
        f"{name}: {result.served}/{result.frames} {what}; {result.baked} maps baked now; "
        f"{result.bytes / 2**20:.1f} MiB of {cfg.codec} maps for {name} in {folder} ({time.perf_counter() - t0:.1f} s)"
    )
    if isinstance(pool, RayExecutor) and pool.nodes:
        per_node = ", ".join(f"{node[:12]} {n}" for node, n in sorted(pool.nodes.items()))
        typer.echo(f"{name}: maps per Ray node: {per_node}")


STORE_HELP = "GI-tree folder (created if missing; shared with cloudbaking-server --store)"
config_command(
    app,
    PrebakeConfig,
    prebake,
    exclude=("tolerance",),
    extras=[
        option_groups.scene_argument(note="a spec file's stem names it in the store"),
        extra("store", Annotated[str, typer.Option("--store", help=STORE_HELP)]),
        *config_options(ToleranceOptions),
        *config_options(ExecutorOptions),
    ],
)


main = entry_point(app, resume="rerun the same command; finished maps are kept and only the rest is baked")
