"""`gicore-dataset`: render training/validation datasets of scene specs (docs/architecture.md, Dataset folder).

    gicore-dataset lung_plane digestive_cornell --out data/ds --train 120 --val 12 --resolution 256
    gicore-dataset lung_plane --out data/ds_gl --renderer gl   # inputs rasterised as the GL client does
    gicore-dataset --random 200 --seed 3 --out data/random      # 200 randomised scenes (gicore.scene_draws)

One folder per scene under ``--out``. ``--renderer`` picks what renders the inputs (DI + G-buffers): Mitsuba
(1-spp DI, G-buffers at a random point of each pixel: what the shipped model trained on) or OpenGL
(:class:`gicore.gl.GLRenderer` at ``--gl-lod``: what a client with ``renderer = "gl"`` feeds the model); the GT
is path-traced by Mitsuba either way, with the same seeds, so two datasets that differ only in ``--renderer``
hold the same GT. ``meta.json`` records the renderer that ran (``gl`` without a GL context falls back to
``mitsuba`` after one warning line). Frames are rendered by the render executor (``gicore.executor``:
this process, ``--workers`` local processes, or Ray tasks with ``--executor ray [--ray-address HOST:PORT]``, the
same options as ``cloudbaking-prebake``; each worker
holds one compiled scene), written atomically by this process as they arrive, and skipped when already
present, so an interrupted run resumes. The same seeds give the same frames on every executor. One run
at a time renders into a scene folder (a second is refused: "another run holds DIR").
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
import typer
from tqdm import tqdm

from gicore import option_groups
from gicore.buffers import DATASET_BUFFERS, TARGET, check_buffer_names
from gicore.camera import Camera
from gicore.dataset import (
    INPUT_RENDERERS,
    SPLITS,
    DatasetMeta,
    FrameRecord,
    as_stored,
    encode_frame,
    write_frame,
    write_meta,
)
from gicore.error_policy import UserError, entry_point
from gicore.executor import Executor, ExecutorOptions, InProcess, Task
from gicore.fileio import exclusive_run, sweep_temporaries
from gicore.gl.lod import LOD_CHOICES, lod_value
from gicore.options import (
    FOV_DEGREES,
    FRAMES_MAX,
    build_config,
    build_options,
    check_fields,
    config_command,
    config_options,
    extra,
)
from gicore.paths import camera_path, frame_seed, light_position
from gicore.run_config import CLIENT_LOD, open_raster
from gicore.scene import SceneSpec, load_scene
from gicore.scene_draws import draw_scenes

if TYPE_CHECKING:
    from gicore.gl import GLRenderer
    from gicore.render import Renderer

app = typer.Typer(add_completion=False, help=__doc__)
RANDOM_HELP = (
    "Also render this many randomised scenes (shapes, colours, lights, environments drawn from --seed: "
    "gicore.scene_draws), one folder each, with their card random_scenes.md/.json in --out"
)
#: Validation paths use a different trajectory seed, so they are held out from the training path.
VAL_SEED_OFFSET = 7919


@dataclass(frozen=True)
class DatasetConfig:
    """How to render one scene's dataset; invalid values raise a UserError naming the option. The command's
    options are derived from these fields (:mod:`gicore.options`)."""

    #: Training frames per scene (paper: 1500); --train and --val together at least 1.
    n_train: int = field(default=60, metadata={"option": "train", "min": 0, "max": FRAMES_MAX})
    #: Validation frames per scene (paper: 100).
    n_val: int = field(default=8, metadata={"option": "val", "min": 0, "max": FRAMES_MAX})
    resolution: int = option_groups.resolution(128, note="paper: 512")
    spp: int = option_groups.spp(note="of the GT")
    denoise: bool = option_groups.denoise()
    seed: int = option_groups.seed(note="the camera trajectories and every frame's render noise")
    #: Camera FOV in degrees; absent: the scene's GI-camera FOV.
    fov: float | None = field(default=None, metadata=FOV_DEGREES)
    #: Buffers rendered and stored (``gicore.buffers``).
    buffers: tuple[str, ...] = DATASET_BUFFERS
    #: Renderer of the inputs (DI + G-buffers): mitsuba (1-spp DI, G-buffers at a random point of each pixel) or
    #: gl (OpenGL at pixel centres, as a client with renderer gl; no GL context: one warning and mitsuba). The GT
    #: is path-traced by Mitsuba either way.
    renderer: Literal[INPUT_RENDERERS] = "mitsuba"  # type: ignore[valid-type]
    #: Level of detail of the gl inputs (gicore.gl.GLRenderer's lod; default the clients'): auto (per view, the
    #: coarsest level within the calibrated G-buffer error bound), full, or a fixed level.
    gl_lod: Literal[LOD_CHOICES] = CLIENT_LOD  # type: ignore[valid-type]

    def __post_init__(self) -> None:
        if min(self.n_train, self.n_val) < 0 or self.n_train + self.n_val < 1:
            raise UserError(
                f"--train {self.n_train} --val {self.n_val} asks for no frames",
                "give --train or --val a count of at least 1",
            )
        check_fields(self)  # the limits of the command line (frame counts, resolution, spp, seed, FOV)
        check_buffer_names(list(self.buffers))


def plan_frames(spec: SceneSpec, cfg: DatasetConfig) -> list[FrameRecord]:
    """Camera, light and matrices of every frame, train then val. The light enters the records only
    when it moves (leave out what the scene does not need)."""
    records = []
    for split, n, path_seed in (("train", cfg.n_train, cfg.seed), ("val", cfg.n_val, cfg.seed + VAL_SEED_OFFSET)):
        if n == 0:
            continue
        for i, cam in enumerate(camera_path(spec, n, seed=path_seed, fov=cfg.fov, resolution=cfg.resolution)):
            # The light schedule runs on the fly-through's frame clock; val uses its own clock offset.
            light = list(light_position(spec, i + (0 if split == "train" else 100_000))) if spec.light.moves else None
            records.append(FrameRecord(split, i, cam.to_dict(), cam.view().tolist(), cam.proj().tolist(), light))
    return records


#: One frame to render: (file under the dataset root, camera fields, light or None, buffers, spp, denoise, render seed).
FrameJob = tuple[str, dict, list | None, tuple[str, ...], int, bool, int]


class FrameRenderer:
    """A worker's renderers of one scene: the inputs (DI + G-buffers) from ``renderer`` (:data:`INPUT_RENDERERS`;
    gl at level of detail ``gl_lod``, one of ``gicore.gl.lod.LOD_CHOICES``), the GT path-traced by Mitsuba.
    Each renderer is opened on first need, so a gl worker that renders no GT never loads Mitsuba."""

    def __init__(self, spec: SceneSpec, resolution: int, renderer: str = "mitsuba", gl_lod: str = CLIENT_LOD):
        if renderer not in INPUT_RENDERERS:
            raise ValueError(f"renderer must be one of {INPUT_RENDERERS}, got {renderer!r}")
        self.spec, self.resolution, self.renderer, self.gl_lod = spec, resolution, renderer, lod_value(gl_lod)
        self._mitsuba: Renderer | None = None
        self._gl: GLRenderer | None = None

    @property
    def mitsuba(self) -> Renderer:
        if self._mitsuba is None:
            from gicore.render import Renderer

            self._mitsuba = Renderer(self.spec, self.resolution)
        return self._mitsuba

    @property
    def gl(self) -> GLRenderer:
        """The GL renderer (:class:`gicore.gl.RasterUnavailable` when no context opens)."""
        if self._gl is None:
            from gicore.gl import GLRenderer

            self._gl = GLRenderer(self.spec, self.resolution, lod=self.gl_lod)
        return self._gl

    def render(
        self, camera: Camera, light: list | None, buffers: tuple[str, ...], spp: int, seed: int, denoise: bool
    ) -> dict[str, np.ndarray]:
        """Exactly the named buffers of one frame (``Renderer.render_frame``'s arguments)."""
        if self.renderer == "mitsuba":
            return self.mitsuba.render_frame(camera, light, buffers, spp=spp, seed=seed, denoise=denoise)
        inputs = [name for name in buffers if name != TARGET]
        out = self.gl.render_frame(camera, light, inputs) if inputs else {}
        if TARGET in buffers:  # the same call as a mitsuba dataset's, so the same GT (OIDN's guides included)
            out |= self.mitsuba.render_frame(camera, light, [TARGET], spp=spp, seed=seed, denoise=denoise)
        return {name: out[name] for name in buffers}


def _build_renderer(spec_dict: dict, resolution: int, renderer: str, gl_lod: str) -> FrameRenderer:
    return FrameRenderer(SceneSpec.from_dict(spec_dict), resolution, renderer, gl_lod)


def _render_frame(renderer: FrameRenderer, job: FrameJob) -> bytes:
    _, cam, light, buffers, spp, denoise, seed = job
    return encode_frame(renderer.render(Camera.from_dict(cam), light, buffers, spp, seed, denoise))


def frame_task(spec: SceneSpec, cfg: DatasetConfig) -> Task:
    """The render task of ``spec``'s frames (a compiled scene per worker; a job's result is its file's bytes)."""
    return Task(_build_renderer, (spec.to_dict(), cfg.resolution, cfg.renderer, cfg.gl_lod), _render_frame)


def frame_jobs(records: list[FrameRecord], cfg: DatasetConfig, root: Path | None = None) -> list[FrameJob]:
    """The jobs of the frames ``records`` (:func:`plan_frames`) that ``root`` does not hold yet (None: all)."""
    return [
        (r.file, r.camera, r.light, cfg.buffers, cfg.spp, cfg.denoise, frame_seed(cfg.seed, r.split, r.index))
        for r in records
        if root is None or not (root / r.file).is_file()
    ]


def render_inputs(renderer: FrameRenderer, meta: DatasetMeta, record: FrameRecord) -> dict[str, np.ndarray]:
    """The inputs (:attr:`DatasetMeta.inputs`) of the dataset frame ``record`` as ``renderer`` renders them: a
    dataset of the same settings made with ``renderer.renderer`` would store exactly these (same camera, light
    and seed, rounded to the storage precision)."""
    seed = frame_seed(meta.seed, record.split, record.index)
    out = renderer.render(Camera.from_dict(record.camera), record.light, tuple(meta.inputs), meta.spp, seed, False)
    return as_stored(out)


def inputs_renderer(meta: DatasetMeta, root: Path, renderer: str, gl_lod: str, option: str) -> FrameRenderer | None:
    """What gives the inputs of the dataset in ``root`` (``meta``) as ``renderer`` draws them (gl at ``gl_lod``):
    None where its stored inputs already are those, else the :class:`FrameRenderer` for :func:`render_inputs`.
    A dataset whose scene spec does not load is a UserError whose fix leaves ``renderer`` out of ``option``."""
    if renderer == meta.renderer and (renderer == "mitsuba" or meta.lod == gl_lod):
        return None
    try:
        spec = SceneSpec.from_dict(meta.scene)
    except (OSError, ValueError) as err:
        raise UserError(
            f"{root} holds {meta.renderer} inputs and its scene spec does not load to render {renderer}'s"
            f" ({' '.join(str(err).split())})",
            f"leave {renderer} out of {option} for it",
        ) from None
    return FrameRenderer(spec, meta.resolution, renderer, gl_lod)


def resolve_renderer(cfg: DatasetConfig) -> DatasetConfig:
    """``cfg`` with the renderer that will run: renderer gl without a GL context falls back to mitsuba after one
    warning line (as the clients do), so the dataset records what rendered it."""
    from gicore.gl import RasterUnavailable, gl_context

    _, used = open_raster(cfg.renderer, None, gl_context, RasterUnavailable)
    return cfg if used == cfg.renderer else replace(cfg, renderer=used)


def build_dataset(
    spec: SceneSpec, root: Path, cfg: DatasetConfig, executor: Executor | None = None, progress: bool = True
) -> DatasetMeta:
    """Render (or finish rendering) ``spec``'s dataset into ``root`` on ``executor`` (default: this
    process); returns its metadata.

    Holds ``root`` for the whole run (a concurrent second run is refused) and first removes temporary
    files that a killed run left behind. Renderer gl without a GL context renders with mitsuba
    (:func:`resolve_renderer`); the metadata returned says which ran."""
    cfg = resolve_renderer(cfg)
    meta = DatasetMeta(
        spec.to_dict(),
        cfg.resolution,
        cfg.spp,
        cfg.denoise,
        cfg.seed,
        list(cfg.buffers),
        plan_frames(spec, cfg),
        renderer=cfg.renderer,
        lod=cfg.gl_lod if cfg.renderer == "gl" else None,
    )
    with exclusive_run(root):
        for folder in (root, *(root / split for split in SPLITS)):
            if folder.is_dir():
                sweep_temporaries(folder)
        write_meta(root, meta)
        jobs = frame_jobs(meta.frames, cfg, root)
        with tqdm(total=len(jobs), desc=spec.name, disable=not (progress and jobs), unit="frame") as bar:

            def receive(job: FrameJob, data: bytes) -> None:
                write_frame(root / job[0], data)
                bar.update()

            (executor or InProcess()).run(frame_task(spec, cfg), jobs, receive)
    return meta


def dataset_command(
    given: dict[str, Any],
    *,
    scenes: list[str],
    random: int,
    out: Path,
    executor: str | None,
    ray_address: str | None,
    workers: int | None,
) -> None:
    """Render datasets for the given scenes."""
    cfg = build_config(DatasetConfig, given)
    run_on = build_options(ExecutorOptions, executor=executor, ray_address=ray_address, workers=workers)
    if not scenes and random == 0:
        raise UserError("no scenes given", "name built-in scenes or spec files, or ask for --random N scenes")
    specs = [load_scene(name) for name in scenes]  # every spec (and mesh) is checked before any rendering
    specs += draw_scenes(cfg.seed, random, out) if random else []
    with run_on.open() as pool:
        for spec in specs:
            root = out / spec.name
            t0 = time.perf_counter()
            meta = build_dataset(spec, root, cfg, pool)
            size = sum(p.stat().st_size for p in root.rglob("*.npz"))
            typer.echo(
                f"{spec.name}: {len(meta.frames)} frames in {root} (inputs by {meta.renderer},"
                f" {size / len(meta.frames) / 1024:.0f} KiB/frame, {time.perf_counter() - t0:.1f} s)"
            )


config_command(
    app,
    DatasetConfig,
    dataset_command,
    extras=[
        option_groups.scenes_argument(".toml or .json; none with --random"),
        extra(
            "random",
            Annotated[int, typer.Option("--random", min=0, max=FRAMES_MAX, help=RANDOM_HELP)],
            0,
        ),
        option_groups.out("one sub-folder per scene", Path("data/datasets")),
        *config_options(ExecutorOptions),
    ],
)

main = entry_point(app, resume="finished frames are kept: run the same command again to render the rest")

if __name__ == "__main__":
    main()
