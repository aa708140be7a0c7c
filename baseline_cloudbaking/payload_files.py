"""The GI tree's payload files: one content-addressed file per stored map (``payloads/ab/<sha256>.gim``),
written atomically (complete and fsynced before the index names it), read through an in-memory LRU, and
swept of what a killed writer left (docs/architecture.md, GI tree).
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from pathlib import Path

from baseline_cloudbaking.store_errors import WouldBlock
from gicore.fileio import atomic_write_bytes, sweep_temporaries

PAYLOAD_SUFFIX = ".gim"


def payload_sha(payload: bytes) -> str:
    """The content address of a payload: its SHA-256, hex (its file name and its HTTP ETag)."""
    return hashlib.sha256(payload).hexdigest()


class PayloadFiles:
    """The payload files under ``folder`` (created if missing) and an LRU of up to ``cache_bytes`` of them in
    memory (0: none). Thread-safe."""

    def __init__(self, folder: Path, cache_bytes: int) -> None:
        if cache_bytes < 0:
            raise ValueError(f"cache_bytes must be >= 0, got {cache_bytes}")
        self.folder = folder
        self.folder.mkdir(parents=True, exist_ok=True)
        self.cache_bytes = cache_bytes
        self.cached_bytes = 0
        self._cached: OrderedDict[str, bytes] = OrderedDict()
        self._lock = threading.Lock()

    def path(self, sha: str) -> Path:
        return self.folder / sha[:2] / f"{sha}{PAYLOAD_SUFFIX}"

    def write(self, sha: str, payload: bytes) -> bool:
        """Write ``payload`` as ``sha``'s file, atomically; returns whether that file existed before."""
        path = self.path(sha)
        existed = path.exists()
        path.parent.mkdir(exist_ok=True)
        atomic_write_bytes(path, payload)
        return existed

    def read(self, sha: str, io: bool = True) -> bytes | None:
        """The payload ``sha`` from the LRU or its file (then kept), or None when the file is gone (removed
        behind our back, or evicted by another process just now); ``io=False``: :class:`WouldBlock` where the
        file would have to be read."""
        with self._lock:
            payload = self._cached.get(sha)
            if payload is not None:
                self._cached.move_to_end(sha)
                return payload
        if not io:
            raise WouldBlock
        try:
            payload = self.path(sha).read_bytes()
        except FileNotFoundError:
            return None
        if len(payload) <= self.cache_bytes:
            with self._lock:
                if sha not in self._cached:
                    self._cached[sha] = payload
                    self.cached_bytes += len(payload)
                while self.cached_bytes > self.cache_bytes:
                    self.cached_bytes -= len(self._cached.popitem(last=False)[1])
        return payload

    def remove(self, shas: list[str]) -> None:
        """Forget and delete the files of ``shas`` (entries the index no longer names)."""
        with self._lock:
            for sha in shas:
                payload = self._cached.pop(sha, None)
                if payload is not None:
                    self.cached_bytes -= len(payload)
        for sha in shas:
            self.path(sha).unlink(missing_ok=True)

    def sweep(self, indexed: dict[str, int]) -> tuple[int, int, dict[str, int]]:
        """Remove temporaries and the files ``indexed`` (sha -> size) does not name; returns how many of each,
        and the size on disk of every indexed file found."""
        temporaries = sum(len(sweep_temporaries(d)) for d in self.folder.iterdir() if d.is_dir())
        orphans = 0
        on_disk: dict[str, int] = {}
        for path in self.folder.glob(f"*/*{PAYLOAD_SUFFIX}"):
            sha = path.name.removesuffix(PAYLOAD_SUFFIX)
            if sha in indexed:
                on_disk[sha] = path.stat().st_size
            else:
                path.unlink()
                orphans += 1
        return temporaries, orphans, on_disk

    def problem(self, entry_id: int, sha: str, size: int) -> str | None:
        """What is wrong with entry ``entry_id``'s file (missing, another size or SHA-256), or None."""
        path = self.path(sha)
        if not path.is_file():
            return f"entry {entry_id}: {path} is missing"
        data = path.read_bytes()
        if len(data) != size or payload_sha(data) != sha:
            return f"entry {entry_id}: {path} has {len(data)} bytes / another SHA-256 than indexed"
        return None
