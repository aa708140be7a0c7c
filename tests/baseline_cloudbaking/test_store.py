"""The GI tree: nearest lookup within tolerance, keys, byte accounting, LRU budget, crash sweeping,
failed writes rolled back and named (a full disk, a read-only index) with nothing left behind, a read-only
index refused at open."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from baseline_cloudbaking.payload_files import payload_sha
from baseline_cloudbaking.store import GITree
from baseline_cloudbaking.store_errors import StoreConflict, StoreUnwritable
from baseline_cloudbaking.viewpoints import MapKey, Tolerance, Viewpoint, light_cell, simulate_fill
from gicore.error_policy import UserError

TOL = Tolerance(position=0.1, angle_deg=5.0)


def key(cell=(0, 0, 0), codec="jpeg", resolution=64, spp=4, di=False, scene="s") -> MapKey:
    return MapKey(scene, cell, resolution, 90.0, codec, spp, di)


def view(x=0.0, y=1.0, z=2.0, target=(0.0, 0.5, 0.0)) -> Viewpoint:
    return Viewpoint.look_at((x, y, z), target)


def blob(i: int, size: int = 1000) -> bytes:
    """An opaque payload (the store never parses payloads): distinct content per ``i``."""
    return np.random.default_rng(i).integers(0, 256, size, dtype=np.uint8).tobytes()


@pytest.fixture
def tree(tmp_path: Path):
    with GITree(tmp_path / "store", tolerance=TOL) as t:
        t.register_scene("s", "sha-s", light_cell_size=0.25)
        yield t


def test_a_tolerance_reads_from_dp_colon_dtheta() -> None:
    assert Tolerance.parse("0.05:2") == Tolerance(0.05, 2.0)
    for bad in ("0.1", "a:b", "0.1:2:3", "-1:2", "nan:2"):
        with pytest.raises(ValueError, match=f"{bad!r} is not DP:DTHETA"):
            Tolerance.parse(bad)


def test_nearest_within_both_tolerances(tree: GITree) -> None:
    a = tree.insert(key(), view(0.0), blob(1))
    b = tree.insert(key(), view(0.15), blob(2))
    hit = tree.lookup(key(), view(0.04))
    assert hit is not None and hit.entry_id == a and hit.payload == blob(1)
    assert hit.distance == pytest.approx(0.04) and hit.lookup_ms > 0
    assert tree.lookup(key(), view(0.12)).entry_id == b  # nearer to b
    assert tree.lookup(key(), view(0.0, z=2.2)) is None  # 0.2 away from both
    # same eye, view turned by ~8.5° (> 5°): a miss although the position matches exactly
    assert tree.lookup(key(), Viewpoint.look_at((0.0, 1.0, 2.0), (0.3, 0.5, 0.0))) is None
    # ... and by ~2.9° (< 5°): a hit
    turned = tree.lookup(key(), Viewpoint.look_at((0.0, 1.0, 2.0), (0.1, 0.5, 0.0)))
    assert turned.entry_id == a and turned.angle_deg == pytest.approx(2.79, abs=0.05)


def test_keys_separate_light_cells_and_formats(tree: GITree) -> None:
    tree.insert(key(), view(), blob(1))
    assert tree.lookup(key(cell=(1, 0, 0)), view()) is None
    for other in (key(codec="webp"), key(resolution=128), key(spp=8), key(di=True)):
        assert tree.lookup(other, view()) is None, other
    # a map that carries DI also serves a request without it
    with_di = tree.insert(key(cell=(2, 0, 0), di=True), view(), blob(2))
    assert tree.lookup(key(cell=(2, 0, 0), di=False), view()).entry_id == with_di


def test_light_cells_and_static_scenes(tmp_path: Path) -> None:
    assert light_cell((0.3, 2.6, -0.1), 0.25) == (1, 10, -1)
    assert light_cell((0.3, 2.6, -0.1), None) is None
    with GITree(tmp_path / "st") as tree:
        tree.register_scene("still", "sha", light_cell_size=None)
        tree.insert(key(cell=None, scene="still"), view(), blob(1))
        with pytest.raises(ValueError, match="static light"):
            tree.insert(key(cell=(0, 0, 0), scene="still"), view(1.0), blob(2))
        assert [e.key.light_cell for e in tree.entries("still")] == [None]
        assert tree.stats()["scenes"] == [{"scene": "still", "light_level": False, "light_cell_size": None}]
    row = sqlite3.connect(tmp_path / "st" / "index.sqlite").execute("SELECT light_cell FROM entries").fetchone()
    assert row == (None,)


def test_scene_registered_under_another_spec_is_refused(tree: GITree) -> None:
    tree.register_scene("s", "sha-s", 0.25)  # idempotent
    with pytest.raises(StoreConflict, match="another spec"):
        tree.register_scene("s", "sha-other", 0.25)
    with pytest.raises(StoreConflict):
        tree.register_scene("s", "sha-s", 0.5)


def test_accounting_per_scene_and_codec(tree: GITree) -> None:
    tree.register_scene("t", "sha-t", 0.25)
    tree.insert(key(), view(0.0), blob(1, 100))
    tree.insert(key(), view(1.0), blob(2, 200))
    tree.insert(key(codec="png"), view(0.0), blob(3, 400))
    tree.insert(key(scene="t"), view(0.0), blob(4, 800))
    stats = tree.stats()
    assert stats["entries"] == 4 and stats["bytes"] == 1500 and stats["inserts"] == 4
    by = {(u["scene"], u["codec"]): (u["entries"], u["bytes"]) for u in stats["by_scene_codec"]}
    assert by == {("s", "jpeg"): (2, 300), ("s", "png"): (1, 400), ("t", "jpeg"): (1, 800)}
    assert tree.verify() == []
    # the same bytes again are the same entry (content addressed), not a second one
    assert tree.insert(key(), view(0.0), blob(1, 100)) == tree.entries()[0].id and tree.stats()["entries"] == 4


def test_budget_evicts_least_recently_used(tmp_path: Path) -> None:
    with GITree(tmp_path / "b", budget_bytes=3500, tolerance=TOL) as tree:
        tree.register_scene("s", "sha", 0.25)
        ids = [tree.insert(key(), view(float(i)), blob(i)) for i in range(3)]  # 3000 bytes
        assert tree.lookup(key(), view(0.0)).entry_id == ids[0]  # entry 0 is now the most recently used
        ids.append(tree.insert(key(), view(3.0), blob(3)))  # 4000 > 3500: evict the LRU one, entry 1
        kept = [e.id for e in tree.entries()]
        assert kept == [ids[0], ids[2], ids[3]]
        for i in range(4, 12):
            tree.insert(key(), view(float(i)), blob(i, 700 + 37 * i))
            stats = tree.stats()
            assert stats["bytes"] <= 3500 and stats["bytes"] == sum(e.bytes for e in tree.entries())
        assert len(list(tree.payload_dir.glob("*/*.gim"))) == stats["entries"]
        assert tree.insert(key(), view(50.0), blob(99, 4000)) is None  # larger than the whole budget
        assert tree.stats()["rejected"] == 1 and tree.verify() == []
        assert stats["evictions"] >= 8


def test_hit_times_persist_for_lru_across_reopen(tmp_path: Path) -> None:
    with GITree(tmp_path / "p", tolerance=TOL) as tree:
        tree.register_scene("s", "sha", 0.25)
        tree.insert(key(), view(0.0), blob(0))
        tree.lookup(key(), view(0.0))
        tree.lookup(key(), view(0.01))
    with GITree(tmp_path / "p", tolerance=TOL) as tree:
        assert [e.hits for e in tree.entries()] == [2]


def test_reopen_sweeps_what_a_killed_writer_left(tmp_path: Path) -> None:
    root = tmp_path / "crash"
    with GITree(root, tolerance=TOL) as tree:
        tree.register_scene("s", "sha", 0.25)
        kept = tree.insert(key(), view(0.0), blob(0))
        lost = tree.insert(key(), view(1.0), blob(1))
        lost_path = tree.payload_path(tree.entries()[1].sha)
    (root / "payloads" / "ab").mkdir(exist_ok=True)
    temp = root / "payloads" / "ab" / "abcd.gim.tmp-x1y2"  # killed mid-write: the temporary file
    temp.write_bytes(b"partial")
    orphan = root / "payloads" / "ab" / ("ab" + "0" * 62 + ".gim")  # killed after the rename, before the commit
    orphan.write_bytes(b"complete but never indexed")
    lost_path.unlink()  # an indexed file that vanished
    with GITree(root, tolerance=TOL) as tree:
        assert tree.swept == {"temporaries": 1, "orphans": 1, "broken_entries": 1}
        assert not temp.exists() and not orphan.exists()
        assert [e.id for e in tree.entries()] == [kept] and lost not in [e.id for e in tree.entries()]
        assert tree.verify() == [] and tree.stats()["bytes"] == len(blob(0))


def test_a_second_opener_does_not_sweep_in_flight_files(tmp_path: Path) -> None:
    root = tmp_path / "shared"
    with GITree(root) as first:
        first.register_scene("s", "sha", 0.25)
        (root / "payloads" / "cd").mkdir()
        in_flight = root / "payloads" / "cd" / ("cd" + "1" * 62 + ".gim")  # renamed by `first`, not yet indexed
        in_flight.write_bytes(b"x")
        with GITree(root) as second:
            assert second.swept == {} and in_flight.exists()
    with GITree(root) as alone:
        assert alone.swept["orphans"] == 1 and not in_flight.exists()


def test_verify_detects_a_tampered_payload(tree: GITree) -> None:
    tree.insert(key(), view(), blob(0))
    path = tree.payload_path(tree.entries()[0].sha)
    path.write_bytes(b"X" + path.read_bytes()[1:])
    assert len(tree.verify()) == 1 and "SHA-256" in tree.verify()[0]


def test_simulated_fill_matches_the_store(tmp_path: Path) -> None:
    """Planning a path's entries without a store (bench storage) agrees with really filling one."""
    rng = np.random.default_rng(5)
    angles = np.cumsum(rng.uniform(0.0, 0.08, 200))
    views = [
        Viewpoint.look_at((2 * np.sin(a), 1.0 + 0.1 * np.sin(3 * a), 2 * np.cos(a)), (0.0, 0.5, 0.0)) for a in angles
    ]
    cells = [light_cell((np.sin(i / 15), 2.5, 0.0), 0.25) for i in range(len(views))]
    served = simulate_fill(views, cells, TOL)
    with GITree(tmp_path / "fill", tolerance=TOL) as tree:
        tree.register_scene("s", "sha", 0.25)
        ids = {}
        for i, (v, c) in enumerate(zip(views, cells, strict=True)):
            hit = tree.lookup(key(cell=c), v)
            ids[i] = hit.entry_id if hit else tree.insert(key(cell=c), v, blob(i, 50))
        assert tree.stats()["entries"] == len(set(served)) == max(served) + 1
    assert 20 < len(set(served)) < 190  # the tolerance really merges frames, and really splits them


def test_concurrent_lookups_and_inserts(tmp_path: Path) -> None:
    with GITree(tmp_path / "conc", tolerance=TOL) as tree:
        tree.register_scene("s", "sha", 0.25)
        errors: list[BaseException] = []

        def work(t: int) -> None:
            try:
                for i in range(30):
                    v = view(float(t * 100 + i))
                    if tree.lookup(key(), v) is None:
                        tree.insert(key(), v, blob(t * 1000 + i, 200))
                    assert tree.lookup(key(), v) is not None
            except BaseException as exc:  # noqa: BLE001 (reported by the assertion below)
                errors.append(exc)

        threads = [threading.Thread(target=work, args=(t,)) for t in range(6)]
        for th in threads:
            th.start()
        for th in threads:
            th.join(timeout=60)
        assert errors == [] and tree.stats()["entries"] == 180 and tree.verify() == []


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="position"):
        Tolerance(position=float("nan"))
    with pytest.raises(ValueError, match="distinct"):
        Viewpoint.look_at((1.0, 1.0, 1.0), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="cell size"):
        light_cell((0.0, 0.0, 0.0), 0.0)


# --- failed writes and read-only stores -----------------------------------------------------------------


@contextmanager
def read_only(path: Path) -> Iterator[None]:
    """``path`` read-only for this process while inside: chmod for a user; root writes through permission
    bits, so for root the file is made immutable (chattr +i; the test is skipped where that is refused)."""
    if os.geteuid() != 0:
        mode = path.stat().st_mode
        path.chmod(0o444)
        try:
            yield
        finally:
            path.chmod(mode)
        return
    if subprocess.run(["chattr", "+i", str(path)], capture_output=True, check=False).returncode != 0:
        pytest.skip("chattr +i is refused here: no way to make a file read-only for root")
    try:
        yield
    finally:
        subprocess.run(["chattr", "-i", str(path)], check=True)


def test_a_read_only_index_is_refused_at_open(tmp_path: Path) -> None:
    root = tmp_path / "ro"
    with GITree(root) as tree:
        tree.register_scene("s", "sha", 0.25)
        tree.insert(key(), view(), blob(0))
    with read_only(root / "index.sqlite"), pytest.raises(UserError) as caught:
        GITree(root)
    assert str(caught.value).startswith(f"{root}/index.sqlite is read-only: make it")
    with GITree(root) as tree:  # writable again: nothing was changed
        assert len(tree.entries()) == 1 and tree.verify() == []


def payload_files(tree: GITree) -> set[str]:
    return {p.name.removesuffix(".gim") for p in tree.payload_dir.glob("*/*.gim")}


def test_a_full_index_names_the_cause_and_the_next_insert_works(tree: GITree) -> None:
    """SQLite rolls a transaction back itself when the disk is full: the error raised is still the full
    disk (not the failed ROLLBACK), one line; nothing of the failed insert is indexed and its payload file
    is gone (no orphan until a restart); the hits it would have written are written by the next insert."""
    first = tree.insert(key(), view(-1.0), blob(9999, 100))
    assert tree.lookup(key(), view(-1.0)).entry_id == first  # one buffered hit
    db = tree.index.db()
    (pages,) = db.execute("PRAGMA page_count").fetchone()
    db.execute(f"PRAGMA max_page_count = {pages}")
    stored = 0
    with pytest.raises(StoreUnwritable, match="database or disk is full") as caught:
        for i in range(1000):
            tree.insert(key(), view(float(i)), blob(i, 100))
            stored += 1
    assert 0 <= stored < 1000 and caught.value.full and isinstance(caught.value.__cause__, sqlite3.OperationalError)
    assert "\n" not in str(caught.value) and str(tree.root) in str(caught.value)
    assert payload_files(tree) == {e.sha for e in tree.entries()}  # no orphan
    db.execute("PRAGMA max_page_count = 1073741823")  # room again
    assert tree.insert(key(), view(5000.0), blob(5000, 100)) is not None
    assert tree.stats()["entries"] == stored + 2 and tree.verify() == []
    assert next(e.hits for e in tree.entries() if e.id == first) == 1


def test_a_full_payload_folder_is_named_and_leaves_no_file(tree: GITree, monkeypatch: pytest.MonkeyPatch) -> None:
    """ENOSPC while the payload is written (the OS's error, as a full file system raises it mid-write)."""
    import errno

    from baseline_cloudbaking import payload_files as files_module

    def full(path: Path, data: bytes, **_: object) -> Path:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(files_module, "atomic_write_bytes", full)
    with pytest.raises(StoreUnwritable, match="No space left on device") as caught:
        tree.insert(key(), view(0.0), blob(0))
    assert caught.value.full and payload_files(tree) == set() and tree.entries() == []
    monkeypatch.undo()
    assert tree.insert(key(), view(0.0), blob(0)) is not None and payload_files(tree) == {payload_sha(blob(0))}


def test_an_index_made_read_only_while_open_is_named_and_recovers(tree: GITree) -> None:
    """The index and its WAL made immutable under an open store: the next insert fails as not writable
    (not full), reads go on, no orphan is left; writable again, the same store inserts without a reopen."""
    first = tree.insert(key(), view(0.0), blob(0))
    index = tree.root / "index.sqlite"
    with read_only(index), read_only(index.with_name("index.sqlite-wal")):
        with pytest.raises(StoreUnwritable, match="cannot write the GI tree") as caught:
            tree.insert(key(), view(1.0), blob(1))
        assert not caught.value.full
        assert tree.lookup(key(), view(0.0)).entry_id == first
        assert payload_files(tree) == {payload_sha(blob(0))}
    assert tree.insert(key(), view(1.0), blob(1)) is not None
    assert len(tree.entries()) == 2 and tree.verify() == []


def test_payload_by_sha(tree: GITree) -> None:
    tree.insert(key(), view(0.0), blob(0))
    assert tree.payload_by_sha(payload_sha(blob(0))) == blob(0)
    assert tree.payload_by_sha(payload_sha(blob(1))) is None
    assert tree.entries()[0].hits == 1


def test_a_failed_flush_rolls_back_and_later_writes_work(tree: GITree) -> None:
    """A write that fails inside its transaction (here a trigger aborts the hit-count update) is rolled
    back and raises its own error; the next writes do not find a transaction still open."""
    first = tree.insert(key(), view(0.0), blob(0))
    db = tree.index.db()
    db.execute("CREATE TRIGGER fail_hits BEFORE UPDATE OF hits ON entries BEGIN SELECT RAISE(ABORT, 'hits lost'); END")
    assert tree.lookup(key(), view(0.0)).entry_id == first  # buffers a hit
    with pytest.raises(sqlite3.IntegrityError, match="hits lost"):
        tree.flush()
    assert not tree.index.db().in_transaction
    second = tree.insert(key(), view(1.0), blob(1))
    assert second is not None and [e.id for e in tree.entries()] == [first, second]
    db.execute("DROP TRIGGER fail_hits")
    tree.lookup(key(), view(1.0))
    assert [e.hits for e in tree.entries()] == [0, 1]


def test_the_few_candidate_path_picks_what_numpy_picks() -> None:
    """GITree.find scores up to 16 candidates in plain floats: the same entry and distances as nearest()."""
    from baseline_cloudbaking.viewpoints import _nearest_few, nearest

    rng = np.random.default_rng(3)
    agreed = 0
    for _ in range(300):
        n = int(rng.integers(1, 17))
        eyes = rng.normal(0.0, 0.06, (n, 3)) + (0.0, 1.0, 2.0)
        dirs = np.array([view(*e).direction for e in eyes]) + rng.normal(0.0, 0.02, (n, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        v = view(*rng.normal(0.0, 0.03, 3) + (0.0, 1.0, 2.0))
        want = nearest(eyes, dirs, v, TOL)
        got = _nearest_few([tuple(e) + tuple(d) for e, d in zip(eyes, dirs)], v, TOL)
        assert (want is None) == (got is None)
        if want is not None:
            assert got[0] == want[0] and got[1:] == pytest.approx(want[1:], rel=1e-9, abs=1e-9)
            agreed += 1
    assert agreed > 100  # most draws have a candidate within tolerance


def test_find_from_memory_picks_what_a_full_scan_picks(tree: GITree) -> None:
    """GITree.find reads a key group's viewpoints once and then a slab of them from memory: over random
    entries (mixed FOVs and DI) and requests, the same entry as nearest() over every entry the index's
    query would have returned."""
    from baseline_cloudbaking.viewpoints import nearest

    rng = np.random.default_rng(7)
    entries = []
    for i in range(150):
        fov, di = (90.0, bool(i % 3)) if i % 5 else (60.0, True)
        eye = tuple(rng.normal(0.0, 0.12, 3) + (0.0, 1.0, 2.0))
        k = MapKey("s", (0, 0, 0), 64, fov, "jpeg", 4, di)
        entries.append((tree.insert(k, view(*eye), blob(1000 + i)), k, view(*eye)))
    agreed = 0
    for _ in range(300):
        want_di = bool(rng.integers(0, 2))
        asked = MapKey("s", (0, 0, 0), 64, 90.0, "jpeg", 4, want_di)
        v = view(*(rng.normal(0.0, 0.12, 3) + (0.0, 1.0, 2.0)))
        pool = [(i, e) for i, k, e in entries if k.fov == 90.0 and (k.di or not want_di)]
        eyes = np.array([e.eye for _, e in pool])
        dirs = np.array([e.direction for _, e in pool])
        want = nearest(eyes, dirs, v, TOL)
        got = tree.find(asked, v)
        assert (want is None) == (got is None)
        if want is not None:
            assert got[0] == pool[want[0]][0] and got[2:] == pytest.approx(want[1:], rel=1e-9, abs=1e-12)
            agreed += 1
    assert agreed > 50


def test_lookups_from_memory_see_every_commit(tmp_path: Path) -> None:
    """``io=False`` answers from memory or raises WouldBlock; an insert or an eviction by another opener (a
    connection of its own, as another process) is seen by the next lookup, never a stale entry."""
    from baseline_cloudbaking.store_errors import WouldBlock

    root = tmp_path / "store"
    with GITree(root, tolerance=TOL) as server, GITree(root, tolerance=TOL, budget_bytes=2500) as other:
        server.register_scene("s", "sha-s", light_cell_size=0.25)
        first = server.insert(key(), view(0.0), blob(1))
        with pytest.raises(WouldBlock):  # a fresh opener has read nothing yet
            other.lookup(key(), view(0.0), io=False)
        assert server.lookup(key(), view(0.0)).entry_id == first
        assert server.lookup(key(), view(0.0), io=False).payload == blob(1)  # index and payload from memory
        assert server.lookup(key(), view(1.0), io=False) is None  # a miss is known without I/O too
        second = other.insert(key(), view(1.0), blob(2))  # another connection commits
        with pytest.raises(WouldBlock):
            server.lookup(key(), view(1.0), io=False)
        assert server.lookup(key(), view(1.0)).entry_id == second
        other.insert(key(), view(2.0), blob(3))  # over other's budget: evicts the least recently used (first)
        assert other.stats()["evictions"] == 1
        assert server.lookup(key(), view(0.0)) is None  # evicted there: not served from this memory
        # this process's own commits are seen too (the version connection never writes)
        third = server.insert(key(), view(3.0), blob(4))
        assert server.lookup(key(), view(3.0)).entry_id == third


def test_the_payload_cache_keeps_to_its_budget(tmp_path: Path) -> None:
    with GITree(tmp_path / "store", tolerance=TOL, cache_bytes=2500) as t:
        t.register_scene("s", "sha-s", light_cell_size=0.25)
        for i in range(4):
            t.insert(key(), view(float(i)), blob(i))
            assert t.lookup(key(), view(float(i))).payload == blob(i)
        assert t.files.cached_bytes == 2000 and len(t.files._cached) == 2  # the two most recent of 1000 bytes each
    with pytest.raises(ValueError, match="cache_bytes must be >= 0"):
        GITree(tmp_path / "other", cache_bytes=-1)


def test_fewest_maps_is_the_smallest_cover_of_the_path() -> None:
    """Views every 0.04 along x; candidate maps every 0.05 and on the views themselves (tolerance 0.1 in
    position, 5 degrees): the count equals the smallest set found by brute force, fewer than the maps a greedy
    fill places; a light cell of its own per map; a view no map serves is an error."""
    import itertools

    from baseline_cloudbaking.viewpoints import fewest_maps, nearest

    views = [view(0.04 * i + 0.001) for i in range(26)]
    cells = [(0, 0, 0)] * len(views)

    def smallest(maps: list) -> int:
        served = [
            frozenset(i for i, v in enumerate(views) if nearest(np.array([m.eye]), np.array([m.direction]), v, TOL))
            for m, _ in maps
        ]
        everything = set(range(len(views)))
        return next(k for k in range(1, len(maps) + 1)
                    for combo in itertools.combinations(served, k) if set().union(*combo) == everything)  # fmt: skip

    for maps in ([(view(0.05 * i), (0, 0, 0)) for i in range(21)], list(zip(views, cells))):
        assert fewest_maps(views, cells, maps, TOL) == smallest(maps)
    assert fewest_maps(views, cells, list(zip(views, cells)), TOL) < max(simulate_fill(views, cells, TOL)) + 1
    with pytest.raises(ValueError, match="no map serves view 0"):
        fewest_maps(views, cells, [(view(0.05 * i), (1, 0, 0)) for i in range(21)], TOL)
    with pytest.raises(ValueError, match="no map serves view 13"):  # a hole around x = 0.52
        fewest_maps(views, cells, [(view(0.05 * i), (0, 0, 0)) for i in range(21) if not 8 < i < 13], TOL)


def test_a_prebake_finds_its_maps_to_rounding(tree: GITree) -> None:
    """cloudbaking-prebake's EXACT: a stored view whose direction differs in the last bit (another normalising
    formula) is the same configuration; a view 1e-6 away is not."""
    from baseline_cloudbaking.prebake_cli import EXACT

    v = view(0.3)
    tree.insert(key(), v, blob(7))
    nudged = Viewpoint(v.eye, tuple(float(c) for c in np.nextafter(np.array(v.direction), 2.0)))
    assert nudged.direction != v.direction and tree.find(key(), nudged, EXACT) is not None
    assert tree.find(key(), view(0.3 + 1e-6), EXACT) is None
