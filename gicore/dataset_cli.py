"""`gicore-dataset`: render training/validation datasets of scene specs (SPEC §3).

    gicore-dataset lung_plane digestive_cornell --out data/ds --train 120 --val 12 --resolution 256

One folder per scene under ``--out``. Frames are rendered by a pool of worker processes (each holds one
compiled scene), written atomically, and skipped when already present, so an interrupted run resumes.
"""

from __future__ import annotations

import multiprocessing
import os
import time
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import typer
from tqdm import tqdm

from gicore.buffers import check_buffer_names
from gicore.camera import Camera
from gicore.dataset import DatasetMeta, FrameRecord, save_frame, write_meta
from gicore.paths import camera_path, light_position
from gicore.scene import SceneSpec, load_scene

app = typer.Typer(add_completion=False, help=__doc__)
DEFAULT_BUFFERS = ("di", "albedo", "normal", "depth", "gt")
#: Validation paths use a different trajectory seed, so they are held out from the training path.
VAL_SEED_OFFSET = 7919


@dataclass(frozen=True)
class DatasetConfig:
    """How to render one scene's dataset."""

    n_train: int = 60
    n_val: int = 8
    resolution: int = 128
    spp: int = 64
    denoise: bool = True
    seed: int = 0
    fov: float | None = None
    buffers: tuple[str, ...] = DEFAULT_BUFFERS


def frame_seed(seed: int, split: str, index: int) -> int:
    """A per-frame render seed: same inputs, same noise; any change, independent noise."""
    return zlib.crc32(f"{seed}/{split}/{index}".encode())


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


def _render_one(job: tuple[str, dict, list | None, tuple[str, ...], int, bool, int]) -> float:
    path, cam, light, buffers, spp, denoise, seed = job
    t0 = time.perf_counter()
    frame = _worker_renderer.render_frame(Camera.from_dict(cam), light, buffers, spp=spp, seed=seed, denoise=denoise)
    save_frame(Path(path), frame)
    return time.perf_counter() - t0


def build_dataset(spec: SceneSpec, root: Path, cfg: DatasetConfig, workers: int = 1, progress: bool = True) -> DatasetMeta:
    """Render (or finish rendering) ``spec``'s dataset into ``root``; returns its metadata."""
    check_buffer_names(list(cfg.buffers))
    meta = DatasetMeta(spec.to_dict(), cfg.resolution, cfg.spp, cfg.denoise, cfg.seed, list(cfg.buffers), plan_frames(spec, cfg))
    write_meta(root, meta)
    jobs = [
        (str(root / r.file), r.camera, r.light, cfg.buffers, cfg.spp, cfg.denoise, frame_seed(cfg.seed, r.split, r.index))
        for r in meta.frames
        if not (root / r.file).is_file()
    ]
    if not jobs:
        return meta
    bar = dict(total=len(jobs), desc=spec.name, disable=not progress, unit="frame")
    if workers == 1:  # no pool: cheaper, and Mitsuba already uses every core
        _init_worker(spec.to_dict(), cfg.resolution, os.cpu_count() or 1)
        for job in tqdm(jobs, **bar):
            _render_one(job)
        return meta
    threads = max(1, (os.cpu_count() or 1) // workers)
    # spawn, not fork: a forked worker inherits OIDN's thread pool state and can deadlock in it.
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(spec.to_dict(), cfg.resolution, threads)) as pool:
        for _ in tqdm(pool.map(_render_one, jobs), **bar):
            pass
    return meta


@app.command()
def main(
    scenes: Annotated[list[str], typer.Argument(help="built-in scene names or spec files (.toml/.json)")],
    out: Annotated[Path, typer.Option(help="root folder; one sub-folder per scene")] = Path("data/datasets"),
    train: Annotated[int, typer.Option(min=0, help="training frames per scene (paper: 1500)")] = 60,
    val: Annotated[int, typer.Option(min=0, help="validation frames per scene (paper: 100)")] = 8,
    resolution: Annotated[int, typer.Option(min=8, max=2048, help="square resolution (paper: 512)")] = 128,
    spp: Annotated[int, typer.Option(min=1, help="path-tracing samples per pixel for GT")] = 64,
    denoise: Annotated[bool, typer.Option(help="denoise GT with Intel OIDN (albedo+normal guided)")] = True,
    seed: Annotated[int, typer.Option(help="seeds trajectories and per-frame noise")] = 0,
    fov: Annotated[float | None, typer.Option(help="camera FOV in degrees (default: the scene's GI-camera FOV)")] = None,
    buffers: Annotated[str, typer.Option(help="comma-separated buffers to render and store")] = ",".join(DEFAULT_BUFFERS),
    workers: Annotated[int, typer.Option(min=1, help="rendering processes")] = 1,
) -> None:
    """Render datasets for the given scenes."""
    cfg = DatasetConfig(train, val, resolution, spp, denoise, seed, fov, tuple(b.strip() for b in buffers.split(",") if b.strip()))
    for name in scenes:
        spec = load_scene(name)
        root = out / spec.name
        t0 = time.perf_counter()
        meta = build_dataset(spec, root, cfg, workers)
        size = sum(p.stat().st_size for p in root.rglob("*.npz"))
        typer.echo(f"{spec.name}: {len(meta.frames)} frames in {root} ({size / len(meta.frames) / 1024:.0f} KiB/frame, {time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    app()
