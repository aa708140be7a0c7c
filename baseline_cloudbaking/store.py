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

import bisect
import errno
import fcntl
import hashlib
import math
import sqlite3
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np

from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes, sweep_temporaries
from gicore.paths import DEFAULT_LIGHT_CELL as DEFAULT_LIGHT_CELL  # the light's space is gicore.paths'

Vec3 = tuple[float, float, float]
PAYLOAD_SUFFIX = ".gim"
INDEX_NAME = "index.sqlite"
READ_ONLY_TODO = "make it, its -wal and -shm files and the store folder writable, or give another --store"
#: Default size of the in-memory LRU of payloads (bytes): a few hundred maps of 256² JPEG.
DEFAULT_CACHE_BYTES = 64 << 20
#: Default payload budget of a server's GI tree (bytes): tens of thousands of 256² maps, and a bound on what
#: requests can make it write.
DEFAULT_BUDGET_BYTES = 4 << 30
_SCHEMA = """
CREATE TABLE IF NOT EXISTS scenes(
    scene TEXT PRIMARY KEY,
    spec_sha TEXT NOT NULL,
    light_cell_size REAL           -- NULL: static light, no light level in this scene's keys
);
CREATE TABLE IF NOT EXISTS entries(
    id INTEGER PRIMARY KEY,
    scene TEXT NOT NULL REFERENCES scenes(scene),
    light_cell TEXT,               -- "i,j,k"; NULL for a static light
    resolution INTEGER NOT NULL, fov REAL NOT NULL, codec TEXT NOT NULL, spp INTEGER NOT NULL, di INTEGER NOT NULL,
    ex REAL NOT NULL, ey REAL NOT NULL, ez REAL NOT NULL,
    dx REAL NOT NULL, dy REAL NOT NULL, dz REAL NOT NULL,
    sha TEXT NOT NULL UNIQUE, bytes INTEGER NOT NULL,
    created REAL NOT NULL, last_used REAL NOT NULL, hits INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS entries_key ON entries(scene, light_cell, resolution, codec, spp, ex);
CREATE INDEX IF NOT EXISTS entries_lru ON entries(last_used);
CREATE TABLE IF NOT EXISTS meta(  -- deletions: entries deleted so far (lookups kept in memory reload on a change)
    name TEXT PRIMARY KEY, value INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS usage(
    scene TEXT NOT NULL, codec TEXT NOT NULL, entries INTEGER NOT NULL, bytes INTEGER NOT NULL,
    PRIMARY KEY(scene, codec)
);
"""


class StoreConflict(ValueError):
    """The store already holds a scene under another spec or light-cell size."""


class StoreClosed(RuntimeError):
    """A call on a :class:`GITree` after :meth:`GITree.close`: the tree does not reopen itself."""


class WouldBlock(Exception):
    """A lookup with ``io=False`` would have to read the index or a payload file: ask again with ``io=True``."""


#: OS errors that mean "no space": the disk or a quota.
_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)
#: OS errors that mean the store cannot be written now (read-only, not permitted, failing storage).
_UNWRITABLE_ERRNOS = (errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG, *_FULL_ERRNOS)
#: SQLite primary result codes of the same conditions (the extended code's low byte).
_SQLITE_FULL = (sqlite3.SQLITE_FULL,)
_SQLITE_UNWRITABLE = (sqlite3.SQLITE_READONLY, sqlite3.SQLITE_IOERR, sqlite3.SQLITE_CANTOPEN, *_SQLITE_FULL)


class StoreUnwritable(UserError):
    """A write to the GI tree failed for a reason outside the request: ``full`` (no space left on its file
    system or quota, or SQLite's page limit) or not (read-only, not permitted, failing storage). One line
    naming the store and the real cause; the original error is the ``__cause__``."""

    def __init__(self, root: Path, cause: str, full: bool) -> None:
        todo = "free space on its file system (or lower the budget)" if full else "make the store writable again"
        super().__init__(f"cannot write the GI tree at {root} ({cause})", todo)
        self.root = root
        self.cause = cause
        self.full = full

    def __reduce__(self) -> tuple:
        return type(self), (self.root, self.cause, self.full)

    @classmethod
    def from_error(cls, root: Path, exc: BaseException) -> StoreUnwritable | None:
        """The StoreUnwritable that ``exc`` means, or None when it is not such a failure (a bug, a constraint)."""
        if isinstance(exc, sqlite3.OperationalError) and getattr(exc, "sqlite_errorcode", None) is not None:
            code = exc.sqlite_errorcode & 0xFF
            if code in _SQLITE_UNWRITABLE:
                return cls(root, f"{exc} (SQLite {exc.sqlite_errorname})", code in _SQLITE_FULL)
        if isinstance(exc, OSError) and exc.errno in _UNWRITABLE_ERRNOS:
            where = f": {exc.filename}" if exc.filename else ""
            return cls(root, f"{exc.strerror or exc}{where}", exc.errno in _FULL_ERRNOS)
        return None


@dataclass(frozen=True)
class Tolerance:
    """How far a stored viewpoint may be from a requested one and still serve it."""

    #: Largest eye distance, scene units.
    position: float = 0.05
    #: Largest angle between the view directions, degrees.
    angle_deg: float = 2.0

    def __post_init__(self) -> None:
        for name in ("position", "angle_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"tolerance {name} must be finite and >= 0, got {v}")


@dataclass(frozen=True)
class Viewpoint:
    """Eye position and unit view direction of a GI camera."""

    eye: Vec3
    direction: Vec3

    @classmethod
    def look_at(cls, eye: Vec3, target: Vec3) -> Viewpoint:
        """Plain floats (a server makes one per request; numpy's per-call cost was most of it)."""
        e = tuple(map(float, eye))
        d = [float(t) - c for t, c in zip(target, e, strict=True)]
        n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if not (math.isfinite(n) and n > 0.0):
            raise ValueError(f"eye {eye} and target {target} must be distinct finite points")
        return cls(e, (d[0] / n, d[1] / n, d[2] / n))  # type: ignore[arg-type]


@dataclass(frozen=True)
class MapKey:
    """Everything but the viewpoint that selects maps: the tree path (scene, light cell) and the map
    format (resolution, GI-camera FOV, codec, spp, whether the GI view's DI is included)."""

    scene: str
    light_cell: tuple[int, int, int] | None
    resolution: int
    fov: float
    codec: str
    spp: int
    di: bool

    @property
    def cell_text(self) -> str | None:
        return None if self.light_cell is None else ",".join(map(str, self.light_cell))


def store_folder(text: str, option: str = "--store") -> Path:
    """The GI-tree folder an option names; UserError when it is empty (``Path("")`` is the working folder)."""
    if not text.strip():
        raise UserError(f"{option} is empty", f"give the GI-tree folder, e.g. {option} gi_store")
    return Path(text)


def payload_sha(payload: bytes) -> str:
    """The content address of a payload: its SHA-256, hex (its file name and its HTTP ETag)."""
    return hashlib.sha256(payload).hexdigest()


def light_cell(light: Vec3, cell_size: float | None) -> tuple[int, int, int] | None:
    """The light level of a key: the grid cell of side ``cell_size`` holding ``light``; ``None`` (no
    light level) when ``cell_size`` is None, i.e. the scene's light does not move."""
    if cell_size is None:
        return None
    if not (math.isfinite(cell_size) and cell_size > 0.0):
        raise ValueError(f"light cell size must be finite and > 0, got {cell_size}")
    return tuple(math.floor(c / cell_size) for c in light)  # type: ignore[return-value]


def nearest(eyes: np.ndarray, dirs: np.ndarray, view: Viewpoint, tol: Tolerance) -> tuple[int, float, float] | None:
    """Index, eye distance and angle (degrees) of the stored viewpoint (rows of ``eyes``/``dirs``) that
    best matches ``view`` within ``tol``, or None. Best = smallest sum of squared tolerance-relative
    distance and angle. Angles use atan2(|a x b|, a.b), exact for tiny angles."""
    if len(eyes) == 0:
        return None
    dp = np.linalg.norm(eyes - np.asarray(view.eye), axis=1)
    d = np.asarray(view.direction)
    angle = np.degrees(np.arctan2(np.linalg.norm(np.cross(dirs, d), axis=1), dirs @ d))
    ok = (dp <= tol.position) & (angle <= tol.angle_deg)
    if not ok.any():
        return None
    score = (dp / max(tol.position, 1e-12)) ** 2 + (angle / max(tol.angle_deg, 1e-12)) ** 2
    i = int(np.argmin(np.where(ok, score, np.inf)))
    return i, float(dp[i]), float(angle[i])


#: Key groups whose viewpoints are kept in memory (requests choose them, e.g. a light cell per light position).
_MAX_GROUPS = 1024
#: Up to this many candidates, :func:`_nearest_few` (plain floats) is cheaper than numpy's per-call cost.
_FEW = 16


def _nearest_few(rows: list[tuple[float, ...]], view: Viewpoint, tol: Tolerance) -> tuple[int, float, float] | None:
    """:func:`nearest` for a few (ex, ey, ez, dx, dy, dz) rows, in plain floats: the same rule and formulas."""
    (x, y, z), (a, b, c) = view.eye, view.direction
    best, best_score = None, math.inf
    for i, (ex, ey, ez, dx, dy, dz) in enumerate(rows):
        dp = math.sqrt((ex - x) ** 2 + (ey - y) ** 2 + (ez - z) ** 2)
        cross = math.sqrt((dy * c - dz * b) ** 2 + (dz * a - dx * c) ** 2 + (dx * b - dy * a) ** 2)
        angle = math.degrees(math.atan2(cross, dx * a + dy * b + dz * c))
        if dp <= tol.position and angle <= tol.angle_deg:
            score = (dp / max(tol.position, 1e-12)) ** 2 + (angle / max(tol.angle_deg, 1e-12)) ** 2
            if score < best_score:
                best, best_score = (i, dp, angle), score
    return best


class ViewSet:
    """Viewpoints in memory (one light cell, one format), for planning a fill without a store."""

    def __init__(self) -> None:
        self._eyes = np.empty((16, 3))
        self._dirs = np.empty((16, 3))
        self.n = 0

    def add(self, view: Viewpoint) -> None:
        if self.n == len(self._eyes):
            self._eyes = np.concatenate([self._eyes, np.empty_like(self._eyes)])
            self._dirs = np.concatenate([self._dirs, np.empty_like(self._dirs)])
        self._eyes[self.n], self._dirs[self.n] = view.eye, view.direction
        self.n += 1

    def nearest(self, view: Viewpoint, tol: Tolerance) -> tuple[int, float, float] | None:
        return nearest(self._eyes[: self.n], self._dirs[: self.n], view, tol)


def simulate_fill(views: list[Viewpoint], cells: list[Any], tol: Tolerance) -> list[int]:
    """Walk a path through an empty tree, inserting on every miss: returns, per frame, the index of
    the entry that serves it (entries are numbered in insertion order; a new index marks a miss)."""
    sets: dict[Any, tuple[ViewSet, list[int]]] = {}
    served: list[int] = []
    n_entries = 0
    for view, cell in zip(views, cells, strict=True):
        vs, ids = sets.setdefault(cell, (ViewSet(), []))
        found = vs.nearest(view, tol)
        if found is None:
            vs.add(view)
            ids.append(n_entries)
            n_entries += 1
            served.append(ids[-1])
        else:
            served.append(ids[found[0]])
    return served


def fewest_maps(views: list[Viewpoint], cells: list[Any], maps: list[tuple[Viewpoint, Any]], tol: Tolerance) -> int:
    """The fewest of ``maps`` (viewpoint, light cell) that serve every view of a path (``views`` with their
    ``cells``, in order) by the GI tree's rule, each view by a map within ``tol`` in its cell: a floor for any
    request policy of a client that must show each view a map within tolerance. Each map serves runs of
    consecutive views; covering the path by such runs, always taking the run reaching farthest from the first
    view not yet served, is optimal for runs. ValueError when some view no map serves."""
    runs: list[tuple[int, int]] = []
    for eye, direction, cell in ((m.eye, m.direction, c) for m, c in maps):
        start = None
        for i, (view, view_cell) in enumerate(zip(views, cells, strict=True)):
            served = view_cell == cell and nearest(np.array([eye]), np.array([direction]), view, tol) is not None
            if served and start is None:
                start = i
            elif not served and start is not None:
                runs.append((start, i - 1))
                start = None
        if start is not None:
            runs.append((start, len(views) - 1))
    count, first = 0, 0
    while first < len(views):
        reach = max((end for start, end in runs if start <= first <= end), default=None)
        if reach is None:
            raise ValueError(f"no map serves view {first} of the path")
        count, first = count + 1, reach + 1
    return count


@dataclass(frozen=True)
class _Views:
    """The viewpoints of one key group (scene, light cell, resolution, codec, spp) in memory, sorted by the
    eye's x (as the index's ``entries_key``) so that a lookup reads only the slab of x within the tolerance;
    FOV and DI are filtered per lookup, as the index's query does."""

    xs: list[float]  # eye x, ascending
    rows: list[tuple]  # (ex, ey, ez, dx, dy, dz, fov, di, id, sha), in the order of xs
    max_id: int  # the largest entry id read (0: none)

    @classmethod
    def from_rows(cls, rows: list[tuple], base: _Views | None = None) -> _Views:
        """From index rows (id, sha, fov, di, ex, ey, ez, dx, dy, dz), added to ``base``'s when given: rows
        newer than all of ``base``'s (their ids are larger) go after its equal x, as the index orders them."""
        new = sorted((r[4:10] + (r[2], r[3], r[0], r[1]) for r in rows), key=lambda r: (r[0], r[8]))
        max_id = max([base.max_id if base else 0, *(r[0] for r in rows)])
        if base is None:
            return cls([r[0] for r in new], new, max_id)
        xs, ordered = base.xs.copy(), base.rows.copy()  # copies: lookups on other threads read the old lists
        for row in new:
            i = bisect.bisect_right(xs, row[0])
            xs.insert(i, row[0])
            ordered.insert(i, row)
        return cls(xs, ordered, max_id)

    def find(self, key: MapKey, view: Viewpoint, tol: Tolerance) -> tuple[int, str, float, float] | None:
        """As :meth:`GITree.find`'s query and rule: the box of side 2 x ``tol.position`` around the eye
        (inclusive, as SQL's BETWEEN), then the nearest within tolerance."""
        (x, y, z), r = view.eye, tol.position
        lo, hi = bisect.bisect_left(self.xs, x - r), bisect.bisect_right(self.xs, x + r)
        candidates = [
            row
            for row in self.rows[lo:hi]
            if y - r <= row[1] <= y + r
            and z - r <= row[2] <= z + r
            and row[7] >= key.di
            and abs(row[6] - key.fov) < 1e-6
        ]
        if not candidates:
            return None
        if len(candidates) <= _FEW:
            found = _nearest_few([row[:6] for row in candidates], view, tol)
        else:
            arr = np.array([row[:6] for row in candidates], dtype=np.float64)
            found = nearest(arr[:, :3], arr[:, 3:], view, tol)
        if found is None:
            return None
        i, dist, angle = found
        return candidates[i][8], candidates[i][9], dist, angle


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


@dataclass(frozen=True)
class Entry:
    """One stored map (a row of the index)."""

    id: int
    key: MapKey
    view: Viewpoint
    sha: str
    bytes: int
    hits: int


class GITree:
    """The GI tree in folder ``root`` (created if missing). Thread-safe: one SQLite connection per
    thread; many processes may open one store (SQLite WAL). ``cache_bytes``: the in-memory LRU of payloads
    (0: none)."""

    def __init__(
        self,
        root: Path,
        budget_bytes: int | None = None,
        tolerance: Tolerance = Tolerance(),
        cache_bytes: int = DEFAULT_CACHE_BYTES,
    ):
        if budget_bytes is not None and budget_bytes <= 0:
            raise ValueError(f"budget_bytes must be > 0 (or None for no budget), got {budget_bytes}")
        if cache_bytes < 0:
            raise ValueError(f"cache_bytes must be >= 0, got {cache_bytes}")
        self.root = Path(root)
        self.payload_dir = self.root / "payloads"
        self.payload_dir.mkdir(parents=True, exist_ok=True)
        self.budget_bytes = budget_bytes
        self.tolerance = tolerance
        self._local = threading.local()
        self._connections: list[sqlite3.Connection] = []
        self._lock = threading.Lock()
        self._touched: dict[int, tuple[float, int]] = {}
        self.counters = {"inserts": 0, "evictions": 0, "rejected": 0}
        self.cache_bytes = cache_bytes
        self._payloads: OrderedDict[str, bytes] = OrderedDict()
        self._payload_bytes = 0
        # key group -> (index version and deletions read at, views); the most recently read last
        self._views_cache: OrderedDict[tuple, tuple[int, int, _Views]] = OrderedDict()
        self._refresh_lock = threading.Lock()  # one thread reads a stale group; the others then find it fresh
        self._version_lock = threading.Lock()
        self._version_db: sqlite3.Connection | None = None
        self._write_lock = threading.Lock()  # an insert, or close(): close never cuts an insert short
        self._closed = False
        try:
            db = self._db()
            db.execute("PRAGMA journal_mode=WAL")
            db.executescript(_SCHEMA)
            self._probe_write(db)
        except sqlite3.OperationalError as exc:
            self._close_connections()
            if exc.sqlite_errorcode & 0xFF == sqlite3.SQLITE_READONLY:
                raise UserError(f"{self.root / INDEX_NAME} is read-only", READ_ONLY_TODO) from exc
            raise
        self._lock_file = open(self.root / "index.lock", "a+b")  # noqa: SIM115 (held for the store's life)
        try:
            fcntl.flock(self._lock_file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.swept: dict[str, int] = {}  # another process has it open: its writes may be in flight
        else:
            self.swept = self._sweep()
        fcntl.flock(self._lock_file.fileno(), fcntl.LOCK_SH)

    # -- connections -------------------------------------------------------------------------------
    def _db(self) -> sqlite3.Connection:
        db = getattr(self._local, "db", None)
        if db is None:
            self._check_open()
            # autocommit mode: transactions are explicit BEGIN IMMEDIATE ... COMMIT
            db = sqlite3.connect(self.root / INDEX_NAME, timeout=30.0, isolation_level=None, check_same_thread=False)
            db.execute("PRAGMA synchronous=NORMAL")  # WAL: commits survive a killed process; payloads are fsynced
            db.execute("PRAGMA foreign_keys=ON")
            self._local.db = db
            with self._lock:
                self._connections.append(db)
        return db

    @staticmethod
    def _probe_write(db: sqlite3.Connection) -> None:
        """Rewrite the index's header page in a transaction rolled back at once: SQLite opens a file it
        may not write read-only without a word, and only a write says so (OperationalError, SQLITE_READONLY)."""
        db.execute("BEGIN IMMEDIATE")
        try:
            (version,) = db.execute("PRAGMA user_version").fetchone()
            db.execute(f"PRAGMA user_version = {int(version)}")
        finally:
            if db.in_transaction:
                db.execute("ROLLBACK")

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` ... ``COMMIT`` on this thread's connection. Any error (in the body or the
        commit) rolls back and propagates as it was: SQLite has sometimes rolled back already (a full
        disk, an I/O error), and a failed ROLLBACK must neither hide the cause nor leave the connection
        inside a transaction (every later BEGIN would fail); such a connection is closed and replaced."""
        db = self._db()
        db.execute("BEGIN IMMEDIATE")
        try:
            yield db
            db.execute("COMMIT")
        except BaseException:
            if db.in_transaction:
                with suppress(sqlite3.Error):
                    db.execute("ROLLBACK")
            if db.in_transaction:
                self._forget(db)
            raise

    def _forget(self, db: sqlite3.Connection) -> None:
        """Close this thread's connection ``db`` (closing rolls back); the next call opens a new one."""
        self._local.db = None
        with self._lock:
            self._connections.remove(db)
        with suppress(sqlite3.Error):
            db.close()

    def _close_connections(self) -> None:
        with self._lock:
            for db in self._connections:
                db.close()
            self._connections.clear()
        self._local = threading.local()
        with self._version_lock:
            if self._version_db is not None:
                self._version_db.close()
                self._version_db = None

    def _check_open(self) -> None:
        if self._closed:
            raise StoreClosed(f"the GI tree at {self.root} is closed: open it again with GITree(...)")

    def close(self) -> None:
        """Write buffered hit times and close every connection and the lock, after an insert in progress
        on another thread; later calls raise :class:`StoreClosed`. Closing again does nothing."""
        with self._write_lock:
            if self._closed:
                return
            try:
                self.flush()
            finally:
                self._closed = True
                self._close_connections()
                self._lock_file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- files -------------------------------------------------------------------------------------
    def payload_path(self, sha: str) -> Path:
        return self.payload_dir / sha[:2] / f"{sha}{PAYLOAD_SUFFIX}"

    def _sweep(self) -> dict[str, int]:
        """Remove temporaries and unindexed payloads; drop entries whose file is gone or wrong-sized."""
        temporaries = sum(len(sweep_temporaries(d)) for d in self.payload_dir.iterdir() if d.is_dir())
        db = self._db()
        rows = {sha: size for sha, size in db.execute("SELECT sha, bytes FROM entries")}
        orphans = 0
        on_disk: dict[str, int] = {}
        for path in self.payload_dir.glob(f"*/*{PAYLOAD_SUFFIX}"):
            sha = path.name.removesuffix(PAYLOAD_SUFFIX)
            if sha in rows:
                on_disk[sha] = path.stat().st_size
            else:
                path.unlink()
                orphans += 1
        broken = [sha for sha, size in rows.items() if on_disk.get(sha) != size]
        if broken:
            with self._transaction() as db:
                db.executemany("DELETE FROM entries WHERE sha = ?", [(s,) for s in broken])
                self._count_deletions(db, len(broken))
                self._recount(db)
        return {"temporaries": temporaries, "orphans": orphans, "broken_entries": len(broken)}

    @staticmethod
    def _count_deletions(db: sqlite3.Connection, n: int) -> None:
        if n:
            db.execute(
                "INSERT INTO meta VALUES ('deletions', ?) "
                "ON CONFLICT(name) DO UPDATE SET value = value + excluded.value",
                (n,),
            )

    @staticmethod
    def _recount(db: sqlite3.Connection) -> None:
        db.execute("DELETE FROM usage")
        db.execute("INSERT INTO usage SELECT scene, codec, COUNT(*), SUM(bytes) FROM entries GROUP BY scene, codec")

    # -- scenes ------------------------------------------------------------------------------------
    def register_scene(self, scene: str, spec_sha: str, light_cell_size: float | None) -> None:
        """Declare ``scene`` (idempotent). ``light_cell_size`` None means a static light: the scene's
        keys have no light level. Refuses (StoreConflict) a scene stored under another spec or cell size."""
        db = self._db()
        row = db.execute("SELECT spec_sha, light_cell_size FROM scenes WHERE scene = ?", (scene,)).fetchone()
        if row is None:
            with self._writing():
                db.execute("INSERT OR IGNORE INTO scenes VALUES (?, ?, ?)", (scene, spec_sha, light_cell_size))
            row = db.execute("SELECT spec_sha, light_cell_size FROM scenes WHERE scene = ?", (scene,)).fetchone()
        if tuple(row) != (spec_sha, light_cell_size):
            raise StoreConflict(
                f"the store at {self.root} holds scene {scene!r} baked from another spec or light-cell size "
                f"(stored {row[0][:12]}, cell {row[1]}; now {spec_sha[:12]}, cell {light_cell_size})"
            )

    def scene_light_cell_size(self, scene: str) -> float | None:
        row = self._db().execute("SELECT light_cell_size FROM scenes WHERE scene = ?", (scene,)).fetchone()
        if row is None:
            raise KeyError(f"scene {scene!r} is not registered in {self.root}")
        return row[0]

    # -- lookup ------------------------------------------------------------------------------------
    def find(
        self, key: MapKey, view: Viewpoint, tol: Tolerance | None = None, io: bool = True
    ) -> tuple[int, str, float, float] | None:
        """(entry id, sha, distance, angle) of the best stored map for ``key``/``view``, or None.
        Pure query: no LRU update. The key group's viewpoints come from memory while the index is unchanged
        (module docstring); ``io=False``: :class:`WouldBlock` where they would have to be read."""
        return self._views(key, io).find(key, view, tol or self.tolerance)

    def index_version(self) -> int:
        """The index's version: it changes with every commit to it, from any connection of any process."""
        with self._version_lock:
            self._check_open()
            if self._version_db is None:  # never writes, so every commit is another connection's
                self._version_db = sqlite3.connect(self.root / INDEX_NAME, timeout=30.0, check_same_thread=False)
            return int(self._version_db.execute("PRAGMA data_version").fetchone()[0])

    def _views(self, key: MapKey, io: bool) -> _Views:
        """The viewpoints of ``key``'s group as of the index's current version: from memory while the index is
        unchanged; after a commit, the entries added since (by id, the table's own order: ids only grow while
        nothing is deleted) merged in, or the whole group read again once entries were deleted (an eviction)."""
        group = (key.scene, key.cell_text, key.resolution, key.codec, key.spp)
        try:
            version = self.index_version()  # before the rows: a commit in between makes them newer, never stale
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
            db = self._db()
            row = db.execute("SELECT value FROM meta WHERE name = 'deletions'").fetchone()
            deletions = 0 if row is None else int(row[0])
            base = cached[2] if cached is not None and cached[1] == deletions else None
            columns = "SELECT id, sha, fov, di, ex, ey, ez, dx, dy, dz FROM entries"
            where = "scene = ? AND light_cell IS ? AND resolution = ? AND codec = ? AND spp = ?"
            if base is None:  # the whole group, through the index on it
                rows = db.execute(f"{columns} WHERE {where}", group).fetchall()
            else:  # what was added since: a range of the table's own ids, then the group's
                rows = db.execute(f"{columns} NOT INDEXED WHERE id > ? AND {where}", (base.max_id, *group)).fetchall()
            views = base if base is not None and not rows else _Views.from_rows(rows, base)
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
        payload = None if found is None else self._payload(found[1], io)
        t2 = time.perf_counter()
        if payload is None:
            return None
        self._touch(found[0])
        return Hit(found[0], found[1], payload, found[2], found[3], (t1 - t0) * 1e3, (t2 - t1) * 1e3)

    def _touch(self, entry_id: int) -> None:
        with self._lock:
            hits = self._touched.get(entry_id, (0.0, 0))[1]
            self._touched[entry_id] = (time.time(), hits + 1)

    def payload_by_sha(self, sha: str) -> bytes | None:
        """The stored payload whose SHA-256 is ``sha`` (counted as a use), or None when no entry has it."""
        row = self._db().execute("SELECT id FROM entries WHERE sha = ?", (sha,)).fetchone()
        payload = None if row is None else self._payload(sha)
        if payload is None:
            return None
        self._touch(int(row[0]))
        return payload

    def _payload(self, sha: str, io: bool = True) -> bytes | None:
        """The payload ``sha`` from the in-memory LRU or its file (then kept), or None when the file is gone
        (removed behind our back, or evicted by another process just now); ``io=False``: WouldBlock where the
        file would have to be read."""
        with self._lock:
            payload = self._payloads.get(sha)
            if payload is not None:
                self._payloads.move_to_end(sha)
                return payload
        if not io:
            raise WouldBlock
        try:
            payload = self.payload_path(sha).read_bytes()
        except FileNotFoundError:
            return None
        if len(payload) <= self.cache_bytes:
            with self._lock:
                if sha not in self._payloads:
                    self._payloads[sha] = payload
                    self._payload_bytes += len(payload)
                while self._payload_bytes > self.cache_bytes:
                    self._payload_bytes -= len(self._payloads.popitem(last=False)[1])
        return payload

    def _uncache(self, shas: list[str]) -> None:
        with self._lock:
            for sha in shas:
                payload = self._payloads.pop(sha, None)
                if payload is not None:
                    self._payload_bytes -= len(payload)

    # -- insert and eviction -------------------------------------------------------------------------
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
            self._check_open()
            entry_id, evicted = self._insert(key, view, payload, sha)
        self._uncache(evicted)
        for old in evicted:  # after the commit: a kill before this leaves orphans, which are swept
            self.payload_path(old).unlink(missing_ok=True)
        with self._lock:
            self.counters["inserts"] += 1
            self.counters["evictions"] += len(evicted)
        return entry_id

    def _insert(self, key: MapKey, view: Viewpoint, payload: bytes, sha: str) -> tuple[int, list[str]]:
        """Write the payload file, then index it in one transaction; on failure remove the file if this
        call created it and nothing indexes it, and keep the buffered hits."""
        path = self.payload_path(sha)
        existed = path.exists()
        path.parent.mkdir(exist_ok=True)
        atomic_write_bytes(path, payload)  # complete and fsynced before the index names it
        now = time.time()
        touched = self._take_touches()
        try:
            with self._transaction() as db:
                self._apply_touches(db, touched)
                existing = db.execute("SELECT id FROM entries WHERE sha = ?", (sha,)).fetchone()
                if existing is not None:  # the same bytes again (a re-bake of an identical request)
                    return int(existing[0]), []
                (x, y, z), (dx, dy, dz) = view.eye, view.direction
                cur = db.execute(
                    "INSERT INTO entries(scene, light_cell, resolution, fov, codec, spp, di, "
                    "ex, ey, ez, dx, dy, dz, sha, bytes, created, last_used) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (key.scene, key.cell_text, key.resolution, key.fov, key.codec, key.spp, int(key.di))
                    + (x, y, z, dx, dy, dz, sha, len(payload), now, now),
                )
                entry_id = int(cur.lastrowid)
                db.execute(
                    "INSERT INTO usage VALUES (?, ?, 1, ?) ON CONFLICT(scene, codec) "
                    "DO UPDATE SET entries = entries + 1, bytes = bytes + excluded.bytes",
                    (key.scene, key.codec, len(payload)),
                )
                evicted = [] if self.budget_bytes is None else self._evict(db, self.budget_bytes, keep=entry_id)
                return entry_id, evicted
        except BaseException as exc:
            self._retouch_if_storage(touched, exc)
            if not existed:
                with suppress(sqlite3.Error):  # unsure whether it is indexed: leave it to the next sweep
                    if self._db().execute("SELECT 1 FROM entries WHERE sha = ?", (sha,)).fetchone() is None:
                        path.unlink(missing_ok=True)
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

    def _evict(self, db: sqlite3.Connection, budget: int, keep: int) -> list[str]:
        """Delete least-recently-used entries (never ``keep``) until the total fits ``budget``."""
        total = db.execute("SELECT COALESCE(SUM(bytes), 0) FROM usage").fetchone()[0]
        evicted = []
        while total > budget:
            rows = db.execute(
                "SELECT id, scene, codec, sha, bytes FROM entries WHERE id != ? ORDER BY last_used, id LIMIT 64",
                (keep,),
            ).fetchall()
            for entry_id, scene, codec, sha, size in rows:
                if total <= budget:
                    break
                db.execute("DELETE FROM entries WHERE id = ?", (entry_id,))
                db.execute(
                    "UPDATE usage SET entries = entries - 1, bytes = bytes - ? WHERE scene = ? AND codec = ?",
                    (size, scene, codec),
                )
                total -= size
                evicted.append(sha)
        db.execute("DELETE FROM usage WHERE entries = 0")
        self._count_deletions(db, len(evicted))
        return evicted

    def _take_touches(self) -> dict[int, tuple[float, int]]:
        with self._lock:
            touched, self._touched = self._touched, {}
        return touched

    def _retouch_if_storage(self, touched: dict[int, tuple[float, int]], exc: BaseException) -> None:
        """Put back hits whose write failed for want of storage (the next write retries them), merged with
        those buffered since; hits whose own update failed otherwise are dropped, or they would fail every
        later write."""
        if StoreUnwritable.from_error(self.root, exc) is None:
            return
        with self._lock:
            for i, (t, n) in touched.items():
                t2, n2 = self._touched.get(i, (0.0, 0))
                self._touched[i] = (max(t, t2), n + n2)

    @staticmethod
    def _apply_touches(db: sqlite3.Connection, touched: dict[int, tuple[float, int]]) -> None:
        db.executemany(
            "UPDATE entries SET last_used = max(last_used, ?), hits = hits + ? WHERE id = ?",
            [(t, n, i) for i, (t, n) in touched.items()],
        )

    def flush(self) -> None:
        """Write buffered hit times and counts to the index (kept buffered if that fails)."""
        if not self._touched:
            return
        touched = self._take_touches()
        try:
            with self._writing(), self._transaction() as db:
                self._apply_touches(db, touched)
        except BaseException as exc:
            self._retouch_if_storage(touched, exc)
            raise

    # -- inspection --------------------------------------------------------------------------------
    def entries(self, scene: str | None = None) -> list[Entry]:
        self.flush()
        sql = (
            "SELECT id, scene, light_cell, resolution, fov, codec, spp, di, ex, ey, ez, dx, dy, dz, sha, bytes, hits "
            "FROM entries"
        )
        rows = (
            self._db()
            .execute(sql + (" WHERE scene = ?" if scene else "") + " ORDER BY id", (scene,) if scene else ())
            .fetchall()
        )
        out = []
        for r in rows:
            cell = None if r[2] is None else tuple(int(c) for c in r[2].split(","))
            key = MapKey(r[1], cell, r[3], r[4], r[5], r[6], bool(r[7]))
            out.append(Entry(r[0], key, Viewpoint(tuple(r[8:11]), tuple(r[11:14])), r[14], r[15], r[16]))
        return out

    def stats(self) -> dict[str, Any]:
        """Entries and bytes (total and per scene and codec), the budget, and this instance's counters."""
        self.flush()
        db = self._db()
        usage = [
            {"scene": s, "codec": c, "entries": n, "bytes": b}
            for s, c, n, b in db.execute("SELECT * FROM usage ORDER BY scene, codec")
        ]
        scenes = [
            {"scene": s, "light_level": size is not None, "light_cell_size": size}
            for s, size in db.execute("SELECT scene, light_cell_size FROM scenes ORDER BY scene")
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
        db = self._db()
        problems = []
        for entry_id, sha, size in db.execute("SELECT id, sha, bytes FROM entries").fetchall():
            path = self.payload_path(sha)
            if not path.is_file():
                problems.append(f"entry {entry_id}: {path} is missing")
                continue
            data = path.read_bytes()
            if len(data) != size or hashlib.sha256(data).hexdigest() != sha:
                problems.append(f"entry {entry_id}: {path} has {len(data)} bytes / another SHA-256 than indexed")
        counted = db.execute(
            "SELECT scene, codec, COUNT(*), SUM(bytes) FROM entries GROUP BY scene, codec ORDER BY scene, codec"
        ).fetchall()
        accounted = db.execute("SELECT * FROM usage ORDER BY scene, codec").fetchall()
        if counted != accounted:
            problems.append(f"usage table {accounted} does not match the entries {counted}")
        return problems
