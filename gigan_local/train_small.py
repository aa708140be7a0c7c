"""The small model a fresh checkout trains and scores: small GIGANs trained on small datasets of a few scenes, so
that the training curves, the model card and the quality scores have a real (if tiny) model to show without the
paper's data set. Torch loads only when a model is trained."""

from __future__ import annotations

from pathlib import Path

from gicore.dataset_cli import DatasetConfig, build_dataset
from gicore.scene import load_scene
from gigan_local.config import TrainConfig

#: The small dataset rendered per scene: 6 training and 3 held-out frames at 256², the shipped model's resolution
#: (about 7 s per scene on 2 cores).
QUICK_DATASET = DatasetConfig(n_train=6, n_val=3, resolution=256, spp=64, denoise=True)


def small_dataset(scene: str, out: Path) -> Path:
    """Render (or finish rendering) ``scene``'s :data:`QUICK_DATASET` into ``out/<scene>``; returns that folder."""
    spec = load_scene(scene)
    root = out / spec.name
    build_dataset(spec, root, QUICK_DATASET, progress=False)
    return root


def train_small(scenes: tuple[str, ...], widths: tuple[int, ...], steps: int, out: Path, seed: int) -> list[Path]:
    """Train one small GIGAN per width for ``steps`` steps on the small datasets of ``scenes`` (rendered into
    ``out/dataset``) into ``out/runs/gigan_ngf<W>``; a finished run is kept, a partial one resumed. Returns the
    run folders."""
    from gigan_local.train import train  # torch loads here

    datasets = [str(small_dataset(scene, out / "dataset")) for scene in scenes]
    runs = []
    for width in widths:
        run_dir = out / "runs" / f"gigan_ngf{width}"
        cfg = TrainConfig(
            model="gigan",
            datasets=datasets,
            ngf=width,
            crop=64,
            batch_size=2,
            epochs=100_000,
            max_steps=steps,
            max_val_frames=QUICK_DATASET.n_val,
            checkpoint_every=0,
            seed=seed,
        )
        train(cfg, run_dir, resume=(run_dir / "checkpoint.pt").is_file(), progress=False)
        runs.append(run_dir)
    return runs
