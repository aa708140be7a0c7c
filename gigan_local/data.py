"""Torch dataset over one or more ``gicore.dataset`` folders: (network input, GI target) pairs.

The encoding of each buffer lives in :mod:`gigan_local.preprocess` (shared with the onnxruntime
client). Encoded frames can be kept in memory (``cache``): decoding an npz frame and encoding its
buffers costs ~30 ms, and caching cut an ngf-16 GIGAN step (batch 8) by about a quarter; the cached
arrays are the very ones a fresh decode gives, so results do not depend on it. Random crops, when
asked for, are drawn from a generator seeded by (seed, epoch, index), so a run and its resumption
see the same crops in the same order whatever the loader does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from gicore.buffers import TARGET
from gicore.dataset import frame_paths, load_frame, read_meta
from gicore.error_policy import UserError
from gigan_local.preprocess import InputSpec, frame_to_input, frame_to_target


def dataset_resolution(roots: list[Path], buffers: tuple[str, ...]) -> int:
    """The common frame size of ``roots``; UserError if they differ or lack a needed buffer."""
    if not roots:
        raise UserError("no dataset folders given", "pass at least one folder made by `gicore-dataset`")
    sizes = {}
    for root in roots:
        meta = read_meta(root)
        missing = [b for b in (*buffers, TARGET) if b not in meta.buffers]
        if missing:
            raise UserError(
                f"dataset {root} has no {missing} buffer(s) (it has {meta.buffers})",
                "render them or drop them from --buffers",
            )
        sizes[str(root)] = meta.resolution
    if len(set(sizes.values())) != 1:
        raise UserError(f"datasets differ in resolution {sizes}", "train on folders rendered at one resolution")
    return next(iter(sizes.values()))


def median_foreground_depth(roots: list[Path], max_frames: int = 16) -> float:
    """Median view depth over the surface pixels of up to ``max_frames`` training frames per folder."""
    depths = []
    for root in roots:
        for path in frame_paths(root, "train")[:max_frames]:
            d = load_frame(path, ["depth"])["depth"]
            depths.append(d[d > 0])
    fg = np.concatenate(depths) if depths else np.empty(0)
    if fg.size == 0:
        raise UserError(
            f"no foreground depth in the training frames of {[str(r) for r in roots]}",
            "render datasets whose frames show the scene",
        )
    return float(np.median(fg))


class FrameDataset(Dataset):
    """Frames of ``split`` from every folder in ``roots``, as (input CxHxW, target 3xHxW) in [-1, 1].

    With ``cache``, each whole encoded frame is kept after its first use (float32, 4 bytes per channel
    and pixel: ~3.4 MB per 256² frame with the default buffers).
    """

    def __init__(
        self,
        roots: list[Path],
        split: str,
        spec: InputSpec,
        crop: int | None = None,
        seed: int = 0,
        cache: bool = False,
    ) -> None:
        self.roots = [Path(r) for r in roots]
        self.spec = spec
        self.resolution = dataset_resolution(self.roots, spec.buffers)
        if crop is not None and not 0 < crop <= self.resolution:
            raise UserError(
                f"--crop {crop} is not between 1 and the frame size {self.resolution}",
                f"give a crop of at most {self.resolution}",
            )
        self.crop = crop
        self.seed = seed
        self.epoch = 0
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] | None = {} if cache else None
        self.paths = [p for r in self.roots for p in frame_paths(r, split)]
        if not self.paths:
            raise UserError(
                f"the {split!r} split of {[str(r) for r in self.roots]} has no frames",
                f"render datasets with {split} frames (gicore-dataset --{split} N)",
            )

    def set_epoch(self, epoch: int) -> None:
        """Select the epoch whose random crops ``__getitem__`` returns."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.paths)

    def _encoded(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        if self._cache is not None and index in self._cache:
            return self._cache[index]
        path = self.paths[index]
        frame = load_frame(path, [*self.spec.buffers, TARGET])
        try:
            pair = frame_to_input(frame, self.spec), frame_to_target(frame, self.spec)
        except ValueError as e:  # NaN/Inf or a wrong shape in a stored frame
            raise UserError(f"{path}: {e}", "delete the frame and rerun `gicore-dataset` to render it again") from e
        if self._cache is not None:
            self._cache[index] = pair
        return pair

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        x, y = self._encoded(index)
        if self.crop is not None and self.crop < self.resolution:
            rng = np.random.default_rng([self.seed, self.epoch, index])
            top, left = rng.integers(0, self.resolution - self.crop + 1, size=2)
            x = x[:, top : top + self.crop, left : left + self.crop]
            y = y[:, top : top + self.crop, left : left + self.crop]
        return torch.tensor(x), torch.tensor(y)  # copies: callers may not alias the cached arrays
