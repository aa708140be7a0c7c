"""On-disk dataset format: one folder per scene.

Layout::

    <root>/meta.json           DatasetMeta: scene spec, render settings (the inputs' renderer among them),
                               buffers, per-frame camera/light
    <root>/train/000000.npz    one compressed array archive per frame, keys = buffer names
    <root>/val/000000.npz

Frames are written atomically (:func:`gicore.fileio.atomic_write_bytes`: a uniquely named temporary file +
rename), so an interrupted run leaves only complete frames and a rerun skips them (resumable).
``meta.json`` is written before any frame; a rerun with different settings is refused rather than
mixing two datasets. Reading a missing, corrupt or truncated ``meta.json`` or frame raises a
:class:`~gicore.error_policy.UserError` that names the file.
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gicore.buffers import CHANNELS, STORAGE_DTYPE, TARGET, check_buffer_names
from gicore.config import strict_from_dict
from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes

FORMAT_VERSION = 1
SPLITS = ("train", "val")
#: Renderers of a dataset's inputs (``gicore.run_config.RENDERERS``); the GT is path-traced by Mitsuba either way.
INPUT_RENDERERS = ("gl", "mitsuba")


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
    #: What rendered the inputs (DI + G-buffers): "mitsuba" (a dataset written before this field was: its
    #: meta.json lacks it) or "gl" (``gicore.gl.GLRenderer``).
    renderer: str = "mitsuba"
    #: The GL renderer's level of detail (``gicore.gl.lod.LOD_CHOICES``); None with "mitsuba".
    lod: str | None = None

    def __post_init__(self) -> None:
        if self.renderer not in INPUT_RENDERERS:
            raise ValueError(f"renderer must be one of {INPUT_RENDERERS}, got {self.renderer!r}")
        if (self.lod is None) != (self.renderer == "mitsuba"):
            raise ValueError(f"lod {self.lod!r} does not go with renderer {self.renderer!r} (gl has one, mitsuba none)")

    @property
    def inputs(self) -> list[str]:
        """The stored buffers the renderer of the inputs made (all but the path-traced GT)."""
        return [name for name in self.buffers if name != TARGET]

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
    def from_dict(cls, d: dict[str, Any]) -> DatasetMeta:
        """Parse a ``meta.json`` document; ValueError names a wrong version or an unknown/missing field."""
        if not isinstance(d, dict) or d.get("format_version") != FORMAT_VERSION:
            version = d.get("format_version") if isinstance(d, dict) else None
            raise ValueError(f"dataset format_version {version} is not {FORMAT_VERSION}")
        meta = strict_from_dict(cls, d, "dataset meta")
        meta.frames = [strict_from_dict(FrameRecord, f, "frame record") for f in meta.frames]
        return meta

    def split_frames(self, split: str) -> list[FrameRecord]:
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        return [f for f in self.frames if f.split == split]


def write_meta(root: Path, meta: DatasetMeta) -> None:
    """Write ``meta.json`` atomically; refuse (UserError) if a different dataset already lives in ``root``."""
    root.mkdir(parents=True, exist_ok=True)
    path = root / "meta.json"
    if path.exists():
        old = read_meta(root).to_dict()
        new = json.loads(json.dumps(meta.to_dict()))
        # Frame i's camera depends on the whole plan (frame count, FOV): a changed plan would leave
        # stored images that no longer match their records.
        differ = [k for k in new if old.get(k) != new[k]]
        if differ:
            shown = ", ".join(f"{k} {old.get(k)!r} -> {new[k]!r}" for k in differ if k not in ("scene", "frames"))
            shown += "".join(f", {k} differs" for k in ("scene", "frames") if k in differ)
            raise UserError(
                f"{root} holds a dataset made with other settings ({shown.lstrip(', ')})",
                "choose another --out or delete that folder",
            )
    atomic_write_bytes(path, json.dumps(meta.to_dict(), indent=1).encode())


def read_meta(root: Path) -> DatasetMeta:
    """The dataset description in ``root/meta.json``; UserError naming the file if missing or unreadable."""
    path = Path(root) / "meta.json"
    if not path.is_file():
        raise UserError(f"no dataset at {root}: {path} is missing", "create one with `gicore-dataset`")
    try:
        return DatasetMeta.from_dict(json.loads(path.read_text()))
    except (ValueError, TypeError) as err:  # JSON syntax, encoding, version, fields and their values
        raise UserError(
            f"{path} is not a readable dataset description ({err})",
            f"delete {root} and render it again with `gicore-dataset`",
        ) from None


def save_frame(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Store a frame's buffers compressed, each in its storage precision, atomically."""
    write_frame(path, encode_frame(arrays))


def write_frame(path: Path, data: bytes) -> None:
    """Write a frame file's bytes (:func:`encode_frame`) atomically, creating its split folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, data)


def encode_frame(arrays: dict[str, np.ndarray]) -> bytes:
    """A frame file's bytes: the buffers compressed, each in its storage precision (a render worker
    encodes; the process that owns the folder writes them with :func:`write_frame`)."""
    check_buffer_names(list(arrays))
    packed = {}
    for name, arr in arrays.items():
        arr = np.asarray(arr)
        if arr.ndim != 3 or arr.shape[-1] != CHANNELS[name]:
            raise ValueError(f"buffer {name!r} must be HxWx{CHANNELS[name]}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"buffer {name!r} contains NaN or Inf; refusing to store it")
        packed[name] = arr.astype(STORAGE_DTYPE[name])
    data = io.BytesIO()
    np.savez_compressed(data, **packed)
    return data.getvalue()


def as_stored(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The buffers as a frame file gives them back: rounded to their storage precision, as float32 (what a
    consumer of freshly rendered buffers uses to see exactly what a stored frame would hold)."""
    return {name: np.asarray(arr).astype(STORAGE_DTYPE[name]).astype(np.float32) for name, arr in arrays.items()}


def load_frame(path: Path, buffers: list[str] | tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """Load a frame's buffers (all, or those named) as float32 HxWxC arrays.

    A missing, truncated or corrupt file, or one without a requested buffer, is a UserError naming it."""
    path = Path(path)
    names = None if buffers is None else list(check_buffer_names(list(buffers)))
    redo = "delete it and rerun `gicore-dataset` with the same options to render it again"
    if not path.is_file():
        raise UserError(f"frame file {path} is missing", "rerun `gicore-dataset` with the same options to render it")
    try:
        with np.load(path, allow_pickle=False) as data:
            stored = list(data.files)
            wanted = stored if names is None else names
            missing = [n for n in wanted if n not in stored]
            arrays = {} if missing else {n: data[n].astype(np.float32) for n in wanted}
    except Exception:  # numpy's npz reader raises many types (BadZipFile, EOFError, zlib.error, ...) on bad bytes
        raise UserError(f"{path} is corrupt or truncated (not a complete .npz frame archive)", redo) from None
    if missing:
        raise UserError(f"{path} lacks buffer(s) {missing} (it has {stored})", redo)
    return arrays


def frame_paths(root: Path, split: str) -> list[Path]:
    """Paths of the frames of ``split`` listed in meta.json, in order (they must all exist)."""
    root = Path(root)
    paths = [root / f.file for f in read_meta(root).split_frames(split)]
    missing = [p for p in paths if not p.is_file()]
    if missing:
        raise UserError(
            f"{len(missing)} frame(s) of {root} are missing, e.g. {missing[0]}",
            "rerun `gicore-dataset` with the same options to finish it",
        )
    return paths
