"""A folder of path-traced renders shared between processes, keyed by everything that made them.

Path tracing is the slow, deterministic part of an evaluation: a bench that runs seven client processes along
one camera path would otherwise path-trace the same GT frames seven times. An entry is an ``.npz`` of named
arrays; its name is the SHA-256 of the JSON of the scene spec and the render's parameters (cameras by their
fields), so a changed spec, camera, light, spp or seed is a different entry. Entries are written atomically:
two processes may render one entry twice, never read a torn one.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gicore.fileio import atomic_write_bytes
from gicore.scene import SceneSpec

Arrays = dict[str, np.ndarray]


def _plain(value: Any) -> Any:
    """JSON form of a key part that ``json`` does not know (dataclasses such as cameras, numpy scalars)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"a render-cache key part must be JSON data or a dataclass, got {type(value).__name__}")


class RenderCache:
    """Renders of one scene spec under ``folder`` (created on the first write)."""

    def __init__(self, folder: Path, spec: SceneSpec) -> None:
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            raise ValueError(f"render cache {self.folder} is a file, not a folder")
        self._scene = spec.to_dict()

    def path(self, key: Any) -> Path:
        """The entry file of ``key`` (any JSON data, dataclasses included)."""
        text = json.dumps([self._scene, key], sort_keys=True, default=_plain)
        return self.folder / f"{hashlib.sha256(text.encode()).hexdigest()}.npz"

    def __contains__(self, key: Any) -> bool:
        return self.path(key).is_file()

    def __getitem__(self, key: Any) -> Arrays:
        try:
            with np.load(self.path(key)) as entry:
                return {name: entry[name] for name in entry.files}
        except FileNotFoundError:
            raise KeyError(key) from None

    def __setitem__(self, key: Any, arrays: Arrays) -> None:
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self.path(key), buf.getvalue(), fsync=False)  # a lost entry is rendered again

    def fetch(self, key: Any, render: Callable[[], Arrays]) -> Arrays:
        """The entry of ``key``, rendered by ``render()`` and stored first when absent."""
        try:
            return self[key]
        except KeyError:
            arrays = render()
        self[key] = arrays
        return arrays
