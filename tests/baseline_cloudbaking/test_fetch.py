"""Where a cloud client's requests run (baseline_cloudbaking.fetch): a worker process hands back the very arrays a
request in the client's own thread decodes, reports failures as a request's status, never hangs when its worker
dies, and leaves no shared-memory file behind. Against a real server process on an ephemeral port, at 64²."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from baseline_cloudbaking.client import RemoteConfig, RemoteSource
from baseline_cloudbaking.fetch import ProcessFetcher, ThreadFetcher
from gicore.gi_map import GIMap
from gicore.paths import path_views
from gicore.scene import load_scene
from tests.helpers.cloud import RES, SPP, server_process, write_scenes


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    scenes = write_scenes(tmp_path_factory.mktemp("fetch_scenes"))
    with server_process(tmp_path_factory.mktemp("fetch_store"), scenes, "--max-spp", "16") as url:
        spec = load_scene(scenes / "ball_moving.json")
        [(camera, light)] = path_views(spec, 1, 300, 0, 60.0, RES)
        yield url, camera.with_fov(90.0), light


def _shared_files() -> set[str]:
    return {p.name for p in Path("/dev/shm").glob("gimap-fetch-*")} if Path("/dev/shm").is_dir() else set()


def test_a_worker_process_hands_back_the_arrays_a_thread_decodes(server) -> None:
    url, camera, light = server
    cfg = RemoteConfig(url, "ball_moving", RES, "jpeg", SPP, di=True)
    body = cfg.body(camera, light)
    before = _shared_files()
    process = ProcessFetcher(cfg)
    thread = ThreadFetcher(cfg)
    try:
        process.ready()
        assert process.warm_up() is None and thread.warm_up() is None
        thread.fetch(body, time.perf_counter())  # the first may miss: both then read the stored map
        mine, theirs = thread.fetch(body, time.perf_counter()), process.fetch(body, time.perf_counter())
    finally:
        process.close()
        thread.close()
    assert mine.fields["status"] == theirs.fields["status"] == "ok" and theirs.fields["hit"] == 1
    for name in ("gi", "di", "depth"):
        a, b = getattr(mine.payload, name), getattr(theirs.payload, name)
        assert a.dtype == b.dtype == np.float32 and np.array_equal(a, b), name
    assert theirs.payload.camera == mine.payload.camera
    assert theirs.fields["handoff_ms"] >= 0 and theirs.t_last <= time.perf_counter()
    assert _shared_files() <= before  # the shared block's file is gone once the worker mapped it


def test_display_maps_come_back_as_their_8bit_values_and_decode_to_the_same_radiance(server) -> None:
    """A client whose warp decodes on the GPU asks for display values: the worker hands back the 8-bit map (no
    linear copy of it), and the GI map's radiance, decoded from it on first use, equals the host decode's."""
    url, camera, light = server
    linear_cfg = RemoteConfig(url, "ball_moving", RES, "jpeg", SPP)
    display_cfg = RemoteConfig(url, "ball_moving", RES, "jpeg", SPP, display=True)
    body = linear_cfg.body(camera, light)
    fetchers = [ThreadFetcher(linear_cfg), ProcessFetcher(display_cfg), ThreadFetcher(display_cfg)]
    try:
        fetchers[1].ready()
        fetchers[0].fetch(body, time.perf_counter())  # the first may miss: then all read the stored map
        linear, *displays = (f.fetch(body, time.perf_counter()).payload for f in fetchers)
    finally:
        for f in fetchers:
            f.close()
    for payload in displays:
        assert payload.gi is None and payload.display.dtype == np.uint8 and payload.display.shape == (RES, RES, 3)
        gi = GIMap(payload.camera, payload.gi, payload.depth, payload.di, display=payload.display)
        assert np.array_equal(gi.radiance, linear.gi) and np.array_equal(payload.depth, linear.depth)


def test_a_failed_request_is_a_status_and_a_dead_worker_ends_its_request(server) -> None:
    url, camera, light = server
    cfg = RemoteConfig(url, "no_such_scene", RES, "jpeg", SPP)
    fetcher = ProcessFetcher(cfg)
    try:
        fetcher.ready()
        failed = fetcher.fetch(cfg.body(camera, light), time.perf_counter())
        assert failed.payload is None and failed.fields["status"] == "http_error"
        os.kill(fetcher._process.pid, signal.SIGKILL)
        dead = fetcher.fetch(cfg.body(camera, light), time.perf_counter())
        assert dead.payload is None and dead.fields["status"] == "connection" and "ended" in dead.fields["error"]
    finally:
        fetcher.close()


def test_a_source_on_worker_processes_records_a_hit_as_its_thread_twin_does(server) -> None:
    url, camera, light = server
    records = {}
    for fetch in ("thread", "process"):
        with RemoteSource(RemoteConfig(url, "ball_moving", RES, "jpeg", SPP, fetch=fetch)) as source:
            source.warm_up(camera, light)
            for frame in range(2):
                assert source.request(camera, light, frame) and source.wait(60.0)
            records[fetch] = source.records[-1]
            assert source.latest().frame == 1
    for record in records.values():
        assert record["status"] == "ok" and record["hit"] == 1 and float(record["decode_ms"]) > 0
        assert float(record["latency_ms"]) >= float(record["request_ms"]) + float(record["decode_ms"])
    assert records["thread"]["handoff_ms"] == "" and float(records["process"]["handoff_ms"]) >= 0
