"""Synthetic gicore datasets and tiny training configs for the training, export and warm-start tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gicore.dataset import DatasetMeta, FrameRecord, save_frame, write_meta
from gigan_local.config import TrainConfig

BUFFERS = ["di", "gt", "albedo", "normal", "depth"]


def _smooth(rng: np.random.Generator, res: int, channels: int, cells: int = 4) -> np.ndarray:
    """A smooth random field in [0, 1] (bilinear upsampling of a cells x cells grid)."""
    grid = rng.random((cells, cells, channels))
    pos = np.linspace(0, cells - 1, res)
    i0 = np.floor(pos).astype(int)
    i1 = np.minimum(i0 + 1, cells - 1)
    t = (pos - i0)[:, None, None]
    rows = grid[i0] * (1 - t) + grid[i1] * t
    t = t.transpose(1, 0, 2)
    return (rows[:, i0] * (1 - t) + rows[:, i1] * t).astype(np.float32)


def synthetic_frame(rng: np.random.Generator, res: int) -> dict[str, np.ndarray]:
    """Plausible smooth buffers whose GI is a fixed function of them (so a network can learn it)."""
    di = 2.0 * _smooth(rng, res, 3)
    albedo = _smooth(rng, res, 3)
    normal = 2.0 * _smooth(rng, res, 3) - 1.0
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    depth = 1.0 + 3.0 * _smooth(rng, res, 1)
    gt = di * (0.5 + albedo) + 0.2 * albedo * (normal[..., 2:3] + 1.0)
    return {"di": di, "gt": gt, "albedo": albedo, "normal": normal, "depth": depth}


def make_dataset(root: Path, res: int = 32, n_train: int = 4, n_val: int = 2, seed: int = 0) -> Path:
    """A gicore dataset folder of synthetic frames."""
    rng = np.random.default_rng(seed)
    eye = np.eye(4).tolist()
    frames = [
        FrameRecord(split, i, {}, eye, eye) for split, n in (("train", n_train), ("val", n_val)) for i in range(n)
    ]
    write_meta(
        root, DatasetMeta(scene={}, resolution=res, spp=1, denoise=False, seed=seed, buffers=BUFFERS, frames=frames)
    )
    for f in frames:
        save_frame(root / f.file, synthetic_frame(rng, res))
    return root


def tiny_config(dataset: Path, **kw) -> TrainConfig:
    return TrainConfig(
        **({"datasets": [str(dataset)], "ngf": 4, "ndf": 4, "batch_size": 2, "checkpoint_every": 0} | kw)
    )
