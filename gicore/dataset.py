"""On-disk dataset format: one folder per scene.

Layout::

    <root>/meta.json           DatasetMeta: scene spec, render settings, buffers, per-frame camera/light
    <root>/train/000000.npz    one compressed array archive per frame, keys = buffer names
    <root>/val/000000.npz

Frames are written atomically (temporary file + rename), so an interrupted run leaves only complete
frames and a rerun skips them (resumable). ``meta.json`` is written before any frame; a rerun with
different settings is refused rather than mixing two datasets.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gicore.buffers import CHANNELS, STORAGE_DTYPE, check_buffer_names

FORMAT_VERSION = 1
SPLITS = ("train", "val")


@dataclass
class FrameRecord:
    """What produced one frame: its split and index, camera, (moving) light and GL matrices."""

    split: str
    index: int
    camera: dict[str, Any]
    view: list[list[float]]
    proj: list[list[float]]
    #: Light position for this frame; absent (None) when the scene's light is static.
    light: list[float] | None = None

    @property
    def file(self) -> str:
        return f"{self.split}/{self.index:06d}.npz"


@dataclass
class DatasetMeta:
    """Everything needed to reproduce or consume a dataset; stored as ``meta.json``."""

    scene: dict[str, Any]
    resolution: int
    spp: int
    denoise: bool
    seed: int
    buffers: list[str]
    frames: list[FrameRecord] = field(default_factory=list)
    format_version: int = FORMAT_VERSION

    def settings(self) -> dict[str, Any]:
        """The render settings (everything but the per-frame records)."""
        d = asdict(self)
        d.pop("frames")
        return d

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["frames"] = [{k: v for k, v in f.items() if v is not None} for f in d["frames"]]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "DatasetMeta":
        d = dict(d)
        if d.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"dataset format_version {d.get('format_version')} is not {FORMAT_VERSION}; regenerate it")
        d["frames"] = [FrameRecord(**f) for f in d.get("frames", [])]
        return cls(**d)

    def split_frames(self, split: str) -> list[FrameRecord]:
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        return [f for f in self.frames if f.split == split]


def write_meta(root: Path, meta: DatasetMeta) -> None:
    """Write ``meta.json`` atomically; refuse if a different dataset already lives in ``root``."""
    root.mkdir(parents=True, exist_ok=True)
    path = root / "meta.json"
    if path.exists():
        old = read_meta(root)
        # Frame i's camera depends on the whole plan (frame count, FOV): a changed plan would leave
        # stored images that no longer match their records.
        if old.to_dict() != json.loads(json.dumps(meta.to_dict())):
            raise ValueError(
                f"{root} holds a dataset made with other settings; choose another --out or delete it.\n"
                f"  existing: {old.settings()}\n  requested: {meta.settings()}"
            )
    _atomic_write_bytes(path, json.dumps(meta.to_dict(), indent=1).encode())


def read_meta(root: Path) -> DatasetMeta:
    path = Path(root) / "meta.json"
    if not path.is_file():
        raise FileNotFoundError(f"no dataset at {root}: {path} is missing (create one with `gicore-dataset`)")
    return DatasetMeta.from_dict(json.loads(path.read_text()))


def save_frame(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Store a frame's buffers compressed, each in its storage precision, atomically."""
    check_buffer_names(list(arrays))
    packed = {}
    for name, arr in arrays.items():
        arr = np.asarray(arr)
        if arr.ndim != 3 or arr.shape[-1] != CHANNELS[name]:
            raise ValueError(f"buffer {name!r} must be HxWx{CHANNELS[name]}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"buffer {name!r} contains NaN or Inf; refusing to store it")
        packed[name] = arr.astype(STORAGE_DTYPE[name])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **packed)
    os.replace(tmp, path)


def load_frame(path: Path, buffers: list[str] | tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """Load a frame's buffers (all, or those named) as float32 HxWxC arrays."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"frame file {path} is missing")
    with np.load(path) as data:
        names = list(data.files) if buffers is None else list(check_buffer_names(list(buffers)))
        missing = [n for n in names if n not in data.files]
        if missing:
            raise KeyError(f"{path} lacks buffer(s) {missing}; it has {data.files}")
        return {n: data[n].astype(np.float32) for n in names}


def frame_paths(root: Path, split: str) -> list[Path]:
    """Paths of the frames of ``split`` listed in meta.json, in order (they must all exist)."""
    root = Path(root)
    paths = [root / f.file for f in read_meta(root).split_frames(split)]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"{len(missing)} frame(s) of {root} are missing, e.g. {missing[0]}; rerun the dataset command to finish it")
    return paths


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)
