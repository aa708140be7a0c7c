"""`gicore-dataset`: render training/validation datasets of scene specs (SPEC §3).

    gicore-dataset lung_plane digestive_cornell --out data/ds --train 120 --val 12 --resolution 256

One folder per scene under ``--out``. Frames are rendered by a pool of worker processes (each holds one
compiled scene), written atomically, and skipped when already present, so an interrupted run resumes.
One run at a time renders into a scene folder (a second is refused: "another run holds DIR").
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import typer
from tqdm import tqdm

from gicore.buffers import DATASET_BUFFERS, check_buffer_names
from gicore.camera import Camera
from gicore.cli import UserError, entry_point, require_between
from gicore.dataset import SPLITS, DatasetMeta, FrameRecord, save_frame, write_meta
from gicore.fileio import exclusive_run, sweep_temporaries
from gicore.paths import camera_path, frame_seed, light_position
from gicore.scene import SceneSpec, load_scene

app = typer.Typer(add_completion=False, help=__doc__)
#: Validation paths use a different trajectory seed, so they are held out from the training path.
VAL_SEED_OFFSET = 7919


@dataclass(frozen=True)
class DatasetConfig:
    """How to render one scene's dataset; invalid values raise a UserError naming the option."""

    #: Training and validation frames (paper: 1500 and 100); together at least one.
    n_train: int = 60
    n_val: int = 8
    #: Square frame side in pixels.
    resolution: int = 128
    #: Path-tracing samples per pixel of the GT.
    spp: int = 64
    #: Denoise the GT with OIDN (albedo + normal guided).
    denoise: bool = True
    #: Seeds the camera trajectories and every frame's render noise.
    seed: int = 0
    #: Camera FOV in degrees; None: the scene's GI-camera FOV.
    fov: float | None = None
    #: Buffers rendered and stored (``gicore.buffers``).
    buffers: tuple[str, ...] = DATASET_BUFFERS

    def __post_init__(self) -> None:
        if min(self.n_train, self.n_val) < 0 or self.n_train + self.n_val < 1:
            raise UserError(f"--train {self.n_train} --val {self.n_val} asks for no frames", "give --train or --val a count of at least 1")
        if not 8 <= self.resolution <= 2048:
            raise UserError(f"--resolution {self.resolution} is outside [8, 2048]", "give a resolution from 8 to 2048")
        if self.spp < 1:
            raise UserError(f"--spp {self.spp} is below 1", "give at least one sample per pixel")
        if self.fov is not None:
            require_between("--fov", self.fov, 0.0, 180.0)
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


_worker_renderer = None


def _init_worker(spec_dict: dict, resolution: int, threads: int) -> None:
    global _worker_renderer
    import drjit as dr

    from gicore.render import Renderer

    dr.set_thread_count(threads)
    _worker_renderer = Renderer(SceneSpec.from_dict(spec_dict), resolution)


def _init_pool_worker(spec_dict: dict, resolution: int, threads: int) -> None:
    """A pool worker leaves Ctrl-C to the parent, which stops the run; the worker finishes its frame."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _init_worker(spec_dict, resolution, threads)


def _render_one(job: tuple[str, dict, list | None, tuple[str, ...], int, bool, int]) -> None:
    path, cam, light, buffers, spp, denoise, seed = job
    frame = _worker_renderer.render_frame(Camera.from_dict(cam), light, buffers, spp=spp, seed=seed, denoise=denoise)
    save_frame(Path(path), frame)


def build_dataset(spec: SceneSpec, root: Path, cfg: DatasetConfig, workers: int = 1, progress: bool = True) -> DatasetMeta:
    """Render (or finish rendering) ``spec``'s dataset into ``root``; returns its metadata.

    Holds ``root`` for the whole run (a concurrent second run is refused) and first removes temporary
    files that a killed run left behind."""
    meta = DatasetMeta(spec.to_dict(), cfg.resolution, cfg.spp, cfg.denoise, cfg.seed, list(cfg.buffers), plan_frames(spec, cfg))
    with exclusive_run(root):
        for folder in (root, *(root / split for split in SPLITS)):
            if folder.is_dir():
                sweep_temporaries(folder)
        write_meta(root, meta)
        _render_missing(spec, root, cfg, meta, workers, progress)
    return meta


def _render_missing(spec: SceneSpec, root: Path, cfg: DatasetConfig, meta: DatasetMeta, workers: int, progress: bool) -> None:
    jobs = [
        (str(root / r.file), r.camera, r.light, cfg.buffers, cfg.spp, cfg.denoise, frame_seed(cfg.seed, r.split, r.index))
        for r in meta.frames
        if not (root / r.file).is_file()
    ]
    if not jobs:
        return
    bar = dict(total=len(jobs), desc=spec.name, disable=not progress, unit="frame")
    if workers == 1:  # no pool: cheaper, and Mitsuba already uses every core
        _init_worker(spec.to_dict(), cfg.resolution, os.cpu_count() or 1)
        for job in tqdm(jobs, **bar):
            _render_one(job)
        return
    threads = max(1, (os.cpu_count() or 1) // workers)
    # spawn, not fork: a forked worker inherits OIDN's thread pool state and can deadlock in it.
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_pool_worker, initargs=(spec.to_dict(), cfg.resolution, threads))
    try:
        for _ in tqdm(pool.map(_render_one, jobs), **bar):
            pass
    except BaseException:  # Ctrl-C or a failed frame: drop the queued frames, let running ones finish their atomic write
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown()


@app.command()
def dataset_command(
    scenes: Annotated[list[str], typer.Argument(help="built-in scene names or spec files (.toml/.json)")],
    out: Annotated[Path, typer.Option(help="root folder; one sub-folder per scene")] = Path("data/datasets"),
    train: Annotated[int, typer.Option(min=0, help="training frames per scene (paper: 1500); --train and --val together at least 1")] = 60,
    val: Annotated[int, typer.Option(min=0, help="validation frames per scene (paper: 100)")] = 8,
    resolution: Annotated[int, typer.Option(min=8, max=2048, help="square resolution (paper: 512)")] = 128,
    spp: Annotated[int, typer.Option(min=1, help="path-tracing samples per pixel for GT")] = 64,
    denoise: Annotated[bool, typer.Option(help="denoise GT with Intel OIDN (albedo+normal guided)")] = True,
    seed: Annotated[int, typer.Option(help="seeds trajectories and per-frame noise")] = 0,
    fov: Annotated[float | None, typer.Option(help="camera FOV in degrees, in (0, 180) (default: the scene's GI-camera FOV)")] = None,
    buffers: Annotated[str, typer.Option(help="comma-separated buffers to render and store")] = ",".join(DATASET_BUFFERS),
    workers: Annotated[int, typer.Option(min=1, help="rendering processes")] = 1,
) -> None:
    """Render datasets for the given scenes."""
    cfg = DatasetConfig(train, val, resolution, spp, denoise, seed, fov, tuple(b.strip() for b in buffers.split(",") if b.strip()))
    specs = [load_scene(name) for name in scenes]  # every spec (and mesh) is checked before any rendering
    for spec in specs:
        root = out / spec.name
        t0 = time.perf_counter()
        meta = build_dataset(spec, root, cfg, workers)
        size = sum(p.stat().st_size for p in root.rglob("*.npz"))
        typer.echo(
            f"{spec.name}: {len(meta.frames)} frames in {root} ({size / len(meta.frames) / 1024:.0f} KiB/frame, {time.perf_counter() - t0:.1f} s)"
        )


main = entry_point(app, resume="finished frames are kept: run the same command again to render the rest")

if __name__ == "__main__":
    main()
