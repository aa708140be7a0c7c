"""The GI tree's index, ``index.sqlite`` (SQLite, WAL): one connection per thread, explicit transactions, and
every query the tree makes of it: scenes, a key group's viewpoints, entries with their usage accounting, the
least-recently-used eviction under a byte budget and the buffered hits (docs/architecture.md, GI tree).
"""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

from baseline_cloudbaking.store_errors import StoreClosed
from baseline_cloudbaking.viewpoints import MapKey, Viewpoint
from gicore.error_policy import UserError

INDEX_NAME = "index.sqlite"
READ_ONLY_TODO = "make it, its -wal and -shm files and the store folder writable, or give another --store"
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
#: Buffered hits: entry id -> (time of the last, how many).
Touches = dict[int, tuple[float, int]]


@dataclass(frozen=True)
class Entry:
    """One stored map (a row of the index)."""

    id: int
    key: MapKey
    view: Viewpoint
    sha: str
    bytes: int
    hits: int


class StoreIndex:
    """The index of the GI tree in folder ``root``. Thread-safe: one connection per thread (autocommit mode:
    transactions are explicit ``BEGIN IMMEDIATE`` ... ``COMMIT``), and one more that only reads the version.
    After :meth:`close` every call raises :class:`StoreClosed`."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.path = root / INDEX_NAME
        self.closed = False
        self._local = threading.local()
        self._connections: list[sqlite3.Connection] = []
        self._lock = threading.Lock()
        self._version_lock = threading.Lock()
        self._version_db: sqlite3.Connection | None = None
        try:
            db = self.db()
            db.execute("PRAGMA journal_mode=WAL")
            db.executescript(_SCHEMA)
            _probe_write(db)
        except sqlite3.OperationalError as exc:
            self._close_connections()
            if exc.sqlite_errorcode & 0xFF == sqlite3.SQLITE_READONLY:
                raise UserError(f"{self.path} is read-only", READ_ONLY_TODO) from exc
            raise

    # -- connections -------------------------------------------------------------------------------
    def check_open(self) -> None:
        if self.closed:
            raise StoreClosed(f"the GI tree at {self.root} is closed: open it again with GITree(...)")

    def db(self) -> sqlite3.Connection:
        """This thread's connection (opened on first use)."""
        db = getattr(self._local, "db", None)
        if db is None:
            self.check_open()
            db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
            db.execute("PRAGMA synchronous=NORMAL")  # WAL: commits survive a killed process; payloads are fsynced
            db.execute("PRAGMA foreign_keys=ON")
            self._local.db = db
            with self._lock:
                self._connections.append(db)
        return db

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """``BEGIN IMMEDIATE`` ... ``COMMIT`` on this thread's connection. Any error (in the body or the
        commit) rolls back and propagates as it was: SQLite has sometimes rolled back already (a full
        disk, an I/O error), and a failed ROLLBACK must neither hide the cause nor leave the connection
        inside a transaction (every later BEGIN would fail); such a connection is closed and replaced."""
        db = self.db()
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

    def close(self) -> None:
        """Close every connection; later calls raise :class:`StoreClosed`."""
        self.closed = True
        self._close_connections()

    def version(self) -> int:
        """The index's version: it changes with every commit to it, from any connection of any process."""
        with self._version_lock:
            self.check_open()
            if self._version_db is None:  # never writes, so every commit is another connection's
                self._version_db = sqlite3.connect(self.path, timeout=30.0, check_same_thread=False)
            return int(self._version_db.execute("PRAGMA data_version").fetchone()[0])

    # -- scenes ------------------------------------------------------------------------------------
    def scene(self, scene: str) -> tuple[str, float | None] | None:
        """``scene``'s spec SHA and light-cell size, or None when it is not registered."""
        row = self.db().execute("SELECT spec_sha, light_cell_size FROM scenes WHERE scene = ?", (scene,)).fetchone()
        return None if row is None else tuple(row)  # type: ignore[return-value]

    def add_scene(self, scene: str, spec_sha: str, light_cell_size: float | None) -> None:
        """Register ``scene`` unless it is (another process may just have)."""
        self.db().execute("INSERT OR IGNORE INTO scenes VALUES (?, ?, ?)", (scene, spec_sha, light_cell_size))

    def scenes(self) -> list[tuple[str, float | None]]:
        return self.db().execute("SELECT scene, light_cell_size FROM scenes ORDER BY scene").fetchall()

    # -- entries -----------------------------------------------------------------------------------
    def deletions(self) -> int:
        """Entries deleted so far (evicted or swept): viewpoints kept in memory are read again after one."""
        row = self.db().execute("SELECT value FROM meta WHERE name = 'deletions'").fetchone()
        return 0 if row is None else int(row[0])

    def group_rows(self, group: tuple, after_id: int | None = None) -> list[tuple]:
        """(id, sha, fov, di, ex, ey, ez, dx, dy, dz) of a key group (scene, light cell text, resolution, codec,
        spp): all of them, through the index on it, or only those added after entry ``after_id`` (a range of
        the table's own ids, then the group's)."""
        columns = "SELECT id, sha, fov, di, ex, ey, ez, dx, dy, dz FROM entries"
        where = "scene = ? AND light_cell IS ? AND resolution = ? AND codec = ? AND spp = ?"
        if after_id is None:
            return self.db().execute(f"{columns} WHERE {where}", group).fetchall()
        return self.db().execute(f"{columns} NOT INDEXED WHERE id > ? AND {where}", (after_id, *group)).fetchall()

    def entry_id(self, sha: str, db: sqlite3.Connection | None = None) -> int | None:
        """The entry whose payload is ``sha``, or None."""
        row = (db or self.db()).execute("SELECT id FROM entries WHERE sha = ?", (sha,)).fetchone()
        return None if row is None else int(row[0])

    @staticmethod
    def add_entry(db: sqlite3.Connection, key: MapKey, view: Viewpoint, sha: str, size: int, now: float) -> int:
        """Index a payload (inside a transaction) and count it in its scene's and codec's usage."""
        (x, y, z), (dx, dy, dz) = view.eye, view.direction
        cur = db.execute(
            "INSERT INTO entries(scene, light_cell, resolution, fov, codec, spp, di, "
            "ex, ey, ez, dx, dy, dz, sha, bytes, created, last_used) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (key.scene, key.cell_text, key.resolution, key.fov, key.codec, key.spp, int(key.di))
            + (x, y, z, dx, dy, dz, sha, size, now, now),
        )
        db.execute(
            "INSERT INTO usage VALUES (?, ?, 1, ?) ON CONFLICT(scene, codec) "
            "DO UPDATE SET entries = entries + 1, bytes = bytes + excluded.bytes",
            (key.scene, key.codec, size),
        )
        return int(cur.lastrowid)

    def evict(self, db: sqlite3.Connection, budget: int, keep: int) -> list[str]:
        """Delete least-recently-used entries (never ``keep``) until the total fits ``budget``; returns their
        payloads' SHAs."""
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
        _count_deletions(db, len(evicted))
        return evicted

    @staticmethod
    def apply_touches(db: sqlite3.Connection, touched: Touches) -> None:
        db.executemany(
            "UPDATE entries SET last_used = max(last_used, ?), hits = hits + ? WHERE id = ?",
            [(t, n, i) for i, (t, n) in touched.items()],
        )

    def sizes(self) -> dict[str, int]:
        """Every indexed payload's SHA and size."""
        return dict(self.db().execute("SELECT sha, bytes FROM entries").fetchall())

    def drop(self, shas: list[str]) -> None:
        """Delete the entries of ``shas`` (their files are gone or wrong-sized) and recount the usage."""
        with self.transaction() as db:
            db.executemany("DELETE FROM entries WHERE sha = ?", [(s,) for s in shas])
            _count_deletions(db, len(shas))
            db.execute("DELETE FROM usage")
            db.execute("INSERT INTO usage SELECT scene, codec, COUNT(*), SUM(bytes) FROM entries GROUP BY scene, codec")

    # -- inspection --------------------------------------------------------------------------------
    def entries(self, scene: str | None = None) -> list[Entry]:
        sql = (
            "SELECT id, scene, light_cell, resolution, fov, codec, spp, di, ex, ey, ez, dx, dy, dz, sha, bytes, hits "
            "FROM entries"
        )
        rows = (
            self.db()
            .execute(sql + (" WHERE scene = ?" if scene else "") + " ORDER BY id", (scene,) if scene else ())
            .fetchall()
        )
        out = []
        for r in rows:
            cell = None if r[2] is None else tuple(int(c) for c in r[2].split(","))
            key = MapKey(r[1], cell, r[3], r[4], r[5], r[6], bool(r[7]))
            out.append(Entry(r[0], key, Viewpoint(tuple(r[8:11]), tuple(r[11:14])), r[14], r[15], r[16]))
        return out

    def usage(self) -> list[tuple[str, str, int, int]]:
        """(scene, codec, entries, bytes), as accounted at each insert and eviction."""
        return self.db().execute("SELECT * FROM usage ORDER BY scene, codec").fetchall()

    def payloads(self) -> list[tuple[int, str, int]]:
        """(entry id, SHA, size) of every entry."""
        return self.db().execute("SELECT id, sha, bytes FROM entries").fetchall()

    def accounting_problem(self) -> str | None:
        """How the usage table differs from the entries it accounts for, or None."""
        counted = (
            self.db()
            .execute(
                "SELECT scene, codec, COUNT(*), SUM(bytes) FROM entries GROUP BY scene, codec ORDER BY scene, codec"
            )
            .fetchall()
        )
        accounted = self.usage()
        return None if counted == accounted else f"usage table {accounted} does not match the entries {counted}"


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


def _count_deletions(db: sqlite3.Connection, n: int) -> None:
    if n:
        db.execute(
            "INSERT INTO meta VALUES ('deletions', ?) ON CONFLICT(name) DO UPDATE SET value = value + excluded.value",
            (n,),
        )
