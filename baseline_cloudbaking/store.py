"""The GI tree: a persistent store of baked GI maps keyed by scene, light cell and viewpoint
(docs/architecture.md, GI tree).

A lookup returns the nearest stored map within a :class:`Tolerance` (eye distance and view angle, in the same
light cell and map format) or a miss. Under one folder: ``index.sqlite`` (SQLite, WAL), one content-addressed
payload file per entry (``payloads/ab/<sha256>.gim``) and ``index.lock``. A payload is written atomically and
only then indexed, so a kill -9 leaves no torn entry (the next opener sweeps what it left); writes are
transactions, and a write that fails for a reason outside the caller raises :class:`StoreUnwritable`. An
optional byte budget evicts least-recently-used entries; hit counts are buffered and written with the next
insert. A closed tree refuses every call with :class:`StoreClosed`, and :meth:`GITree.close` waits for an
insert in progress. Lookups are answered from memory while the index is unchanged (``PRAGMA data_version``),
and ``lookup(..., io=False)`` raises :class:`WouldBlock` rather than read a file, so a server answers most
hits on its event loop.
"""

from __future__ import annotations

import fcntl
import sqlite3
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

from baseline_cloudbaking.payload_files import PayloadFiles, payload_sha
from baseline_cloudbaking.store_errors import StoreConflict, StoreUnwritable, WouldBlock
from baseline_cloudbaking.store_index import Entry, StoreIndex, Touches
from baseline_cloudbaking.viewpoints import GroupViews, MapKey, Tolerance, Viewpoint
from gicore.error_policy import UserError
from gicore.paths import DEFAULT_LIGHT_CELL as DEFAULT_LIGHT_CELL  # the light's space is gicore.paths'

#: Default size of the in-memory LRU of payloads (bytes): a few hundred maps of 256² JPEG.
DEFAULT_CACHE_BYTES = 64 << 20
#: Default payload budget of a server's GI tree (bytes): tens of thousands of 256² maps, and a bound on what
#: requests can make it write.
DEFAULT_BUDGET_BYTES = 4 << 30
#: The tolerance a tree serves lookups with unless given another.
DEFAULT_TOLERANCE = Tolerance()
#: Key groups whose viewpoints are kept in memory (requests choose them, e.g. a light cell per light position).
_MAX_GROUPS = 1024


def store_folder(text: str, option: str = "--store") -> Path:
    """The GI-tree folder an option names; UserError when it is empty (``Path("")`` is the working folder)."""
    if not text.strip():
        raise UserError(f"{option} is empty", f"give the GI-tree folder, e.g. {option} gi_store")
    return Path(text)


@dataclass(frozen=True)
class Hit:
    """A lookup that found a map: its entry id, payload bytes, how far it is from the request, and
    what the lookup (SQL + nearest test) and the payload read cost."""

    entry_id: int
    sha: str
    payload: bytes
    distance: float
    angle_deg: float
    lookup_ms: float
    read_ms: float


class GITree:
    """The GI tree in folder ``root`` (created if missing): its index (:mod:`baseline_cloudbaking.store_index`)
    and payload files (:mod:`baseline_cloudbaking.payload_files`). Thread-safe: one SQLite connection per
    thread; many processes may open one store (SQLite WAL). ``cache_bytes``: the in-memory LRU of payloads
    (0: none)."""

    def __init__(
        self,
        root: Path,
        budget_bytes: int | None = None,
        tolerance: Tolerance = DEFAULT_TOLERANCE,
        cache_bytes: int = DEFAULT_CACHE_BYTES,
    ):
        if budget_bytes is not None and budget_bytes <= 0:
            raise ValueError(f"budget_bytes must be > 0 (or None for no budget), got {budget_bytes}")
        self.root = Path(root)
        self.files = PayloadFiles(self.root / "payloads", cache_bytes)
        self.payload_dir = self.files.folder
        self.budget_bytes = budget_bytes
        self.tolerance = tolerance
        self._lock = threading.Lock()
        self._touched: Touches = {}
        self.counters = {"inserts": 0, "evictions": 0, "rejected": 0}
        # key group -> (index version and deletions read at, views); the most recently read last
        self._views_cache: OrderedDict[tuple, tuple[int, int, GroupViews]] = OrderedDict()
        self._refresh_lock = threading.Lock()  # one thread reads a stale group; the others then find it fresh
        self._write_lock = threading.Lock()  # an insert, or close(): close never cuts an insert short
        self.index = StoreIndex(self.root)
        self._lock_file = open(self.root / "index.lock", "a+b")  # noqa: SIM115 (held for the store's life)
        try:
            fcntl.flock(self._lock_file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.swept: dict[str, int] = {}  # another process has it open: its writes may be in flight
        else:
            self.swept = self._sweep()
        fcntl.flock(self._lock_file.fileno(), fcntl.LOCK_SH)

    def close(self) -> None:
        """Write buffered hit times and close every connection and the lock, after an insert in progress
        on another thread; later calls raise :class:`~baseline_cloudbaking.store_errors.StoreClosed`. Closing
        again does nothing."""
        with self._write_lock:
            if self.index.closed:
                return
            try:
                self.flush()
            finally:
                self.index.close()
                self._lock_file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def payload_path(self, sha: str) -> Path:
        return self.files.path(sha)

    def _sweep(self) -> dict[str, int]:
        """Remove temporaries and unindexed payloads; drop entries whose file is gone or wrong-sized."""
        indexed = self.index.sizes()
        temporaries, orphans, on_disk = self.files.sweep(indexed)
        broken = [sha for sha, size in indexed.items() if on_disk.get(sha) != size]
        if broken:
            self.index.drop(broken)
        return {"temporaries": temporaries, "orphans": orphans, "broken_entries": len(broken)}

    # -- scenes ------------------------------------------------------------------------------------
    def register_scene(self, scene: str, spec_sha: str, light_cell_size: float | None) -> None:
        """Declare ``scene`` (idempotent). ``light_cell_size`` None means a static light: the scene's
        keys have no light level. Refuses (StoreConflict) a scene stored under another spec or cell size."""
        row = self.index.scene(scene)
        if row is None:
            with self._writing():
                self.index.add_scene(scene, spec_sha, light_cell_size)
            row = self.index.scene(scene)
        if row != (spec_sha, light_cell_size):
            raise StoreConflict(
                f"the store at {self.root} holds scene {scene!r} baked from another spec or light-cell size "
                f"(stored {row[0][:12]}, cell {row[1]}; now {spec_sha[:12]}, cell {light_cell_size})"
            )

    def scene_light_cell_size(self, scene: str) -> float | None:
        row = self.index.scene(scene)
        if row is None:
            raise KeyError(f"scene {scene!r} is not registered in {self.root}")
        return row[1]

    # -- lookup ------------------------------------------------------------------------------------
    def find(
        self, key: MapKey, view: Viewpoint, tol: Tolerance | None = None, io: bool = True
    ) -> tuple[int, str, float, float] | None:
        """(entry id, sha, distance, angle) of the best stored map for ``key``/``view``, or None.
        Pure query: no LRU update. The key group's viewpoints come from memory while the index is unchanged
        (module docstring); ``io=False``: :class:`WouldBlock` where they would have to be read."""
        return self._views(key, io).find(key, view, tol or self.tolerance)

    def _views(self, key: MapKey, io: bool) -> GroupViews:
        """The viewpoints of ``key``'s group as of the index's current version: from memory while the index is
        unchanged; after a commit, the entries added since (by id, the table's own order: ids only grow while
        nothing is deleted) merged in, or the whole group read again once entries were deleted (an eviction)."""
        group = (key.scene, key.cell_text, key.resolution, key.codec, key.spp)
        try:
            version = self.index.version()  # before the rows: a commit in between makes them newer, never stale
        except sqlite3.OperationalError:
            if io:
                raise
            raise WouldBlock from None  # busy: a thread waits for it
        cached = self._views_cache.get(group)
        if cached is not None and cached[0] == version:
            return cached[2]
        if not io:
            raise WouldBlock
        with self._refresh_lock:
            cached = self._views_cache.get(group)
            if cached is not None and cached[0] == version:
                return cached[2]
            deletions = self.index.deletions()
            base = cached[2] if cached is not None and cached[1] == deletions else None
            rows = self.index.group_rows(group, None if base is None else base.max_id)
            views = base if base is not None and not rows else GroupViews.from_rows(rows, base)
            with self._lock:
                self._views_cache[group] = (version, deletions, views)
                self._views_cache.move_to_end(group)
                while len(self._views_cache) > _MAX_GROUPS:  # requests choose the groups: keep the latest read
                    self._views_cache.popitem(last=False)
        return views

    def lookup(self, key: MapKey, view: Viewpoint, tol: Tolerance | None = None, io: bool = True) -> Hit | None:
        """The nearest stored map within tolerance (its payload from memory or disk), or None (a miss).
        ``io=False``: from memory alone, else :class:`WouldBlock`."""
        t0 = time.perf_counter()
        found = self.find(key, view, tol, io)
        t1 = time.perf_counter()
        payload = None if found is None else self.files.read(found[1], io)
        t2 = time.perf_counter()
        if payload is None:
            return None
        self._touch(found[0])
        return Hit(found[0], found[1], payload, found[2], found[3], (t1 - t0) * 1e3, (t2 - t1) * 1e3)

    def payload_by_sha(self, sha: str) -> bytes | None:
        """The stored payload whose SHA-256 is ``sha`` (counted as a use), or None when no entry has it."""
        entry_id = self.index.entry_id(sha)
        payload = None if entry_id is None else self.files.read(sha)
        if payload is None:
            return None
        self._touch(entry_id)
        return payload

    # -- insert ------------------------------------------------------------------------------------
    def insert(self, key: MapKey, view: Viewpoint, payload: bytes) -> int | None:
        """Store a payload for ``key``/``view`` (the scene must be registered); returns its entry id, or
        None if the payload alone exceeds the budget (nothing is stored then). StoreUnwritable when the
        store cannot take it (nothing of it is left behind then)."""
        size = len(payload)
        if self.budget_bytes is not None and size > self.budget_bytes:
            with self._lock:
                self.counters["rejected"] += 1
            return None
        cell_size = self.scene_light_cell_size(key.scene)
        if (cell_size is None) != (key.light_cell is None):
            kind = "a static light (no light level)" if cell_size is None else "a moving light (keys need a light cell)"
            raise ValueError(f"scene {key.scene!r} has {kind}; got light_cell={key.light_cell}")
        sha = payload_sha(payload)
        with self._write_lock, self._writing():
            self.index.check_open()
            entry_id, evicted = self._insert(key, view, payload, sha)
        self.files.remove(evicted)  # after the commit: a kill before this leaves orphans, which are swept
        with self._lock:
            self.counters["inserts"] += 1
            self.counters["evictions"] += len(evicted)
        return entry_id

    def _insert(self, key: MapKey, view: Viewpoint, payload: bytes, sha: str) -> tuple[int, list[str]]:
        """Write the payload file, then index it in one transaction; on failure remove the file if this
        call created it and nothing indexes it, and keep the buffered hits."""
        existed = self.files.write(sha, payload)  # complete and fsynced before the index names it
        now = time.time()
        touched = self._take_touches()
        try:
            with self.index.transaction() as db:
                self.index.apply_touches(db, touched)
                existing = self.index.entry_id(sha, db)
                if existing is not None:  # the same bytes again (a re-bake of an identical request)
                    return existing, []
                entry_id = self.index.add_entry(db, key, view, sha, len(payload), now)
                evicted = [] if self.budget_bytes is None else self.index.evict(db, self.budget_bytes, keep=entry_id)
                return entry_id, evicted
        except BaseException as exc:
            self._retouch_if_storage(touched, exc)
            if not existed:
                with suppress(sqlite3.Error):  # unsure whether it is indexed: leave it to the next sweep
                    if self.index.entry_id(sha) is None:
                        self.files.remove([sha])
            raise

    @contextmanager
    def _writing(self) -> Iterator[None]:
        """Turn a failure of the storage (full, read-only, failing) into :class:`StoreUnwritable`."""
        try:
            yield
        except (sqlite3.OperationalError, OSError) as exc:
            failure = StoreUnwritable.from_error(self.root, exc)
            if failure is None:
                raise
            raise failure from exc

    # -- buffered hits -----------------------------------------------------------------------------
    def _touch(self, entry_id: int) -> None:
        with self._lock:
            hits = self._touched.get(entry_id, (0.0, 0))[1]
            self._touched[entry_id] = (time.time(), hits + 1)

    def _take_touches(self) -> Touches:
        with self._lock:
            touched, self._touched = self._touched, {}
        return touched

    def _retouch_if_storage(self, touched: Touches, exc: BaseException) -> None:
        """Put back hits whose write failed for want of storage (the next write retries them), merged with
        those buffered since; hits whose own update failed otherwise are dropped, or they would fail every
        later write."""
        if StoreUnwritable.from_error(self.root, exc) is None:
            return
        with self._lock:
            for i, (t, n) in touched.items():
                t2, n2 = self._touched.get(i, (0.0, 0))
                self._touched[i] = (max(t, t2), n + n2)

    def flush(self) -> None:
        """Write buffered hit times and counts to the index (kept buffered if that fails)."""
        if not self._touched:
            return
        touched = self._take_touches()
        try:
            with self._writing(), self.index.transaction() as db:
                self.index.apply_touches(db, touched)
        except BaseException as exc:
            self._retouch_if_storage(touched, exc)
            raise

    # -- inspection --------------------------------------------------------------------------------
    def entries(self, scene: str | None = None) -> list[Entry]:
        self.flush()
        return self.index.entries(scene)

    def stats(self) -> dict[str, Any]:
        """Entries and bytes (total and per scene and codec), the budget, and this instance's counters."""
        self.flush()
        usage = [{"scene": s, "codec": c, "entries": n, "bytes": b} for s, c, n, b in self.index.usage()]
        scenes = [
            {"scene": s, "light_level": size is not None, "light_cell_size": size} for s, size in self.index.scenes()
        ]
        with self._lock:
            counters = dict(self.counters)
        return {
            "entries": sum(u["entries"] for u in usage),
            "bytes": sum(u["bytes"] for u in usage),
            "budget_bytes": self.budget_bytes,
            "by_scene_codec": usage,
            "scenes": scenes,
            **counters,
        }

    def verify(self) -> list[str]:
        """Problems found by re-reading every indexed payload (missing, wrong size, wrong SHA-256) and
        re-adding the accounting; empty when the store is consistent."""
        problems = [self.files.problem(entry_id, sha, size) for entry_id, sha, size in self.index.payloads()]
        problems.append(self.index.accounting_problem())
        return [p for p in problems if p is not None]
