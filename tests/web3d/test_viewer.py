"""bench web end to end on a tiny run (headless Chromium, SwiftShader WebGL2; gigan-web's own children: a
cloudbaking-server on a store prebaked along the path, a network-sim proxy per profile): the path replays through
the page's camera API once per profile, each system's frame times, map ages, perceived latency, stages and
checks land in the CSV and its tables, the browser's prediction matches GIModel.predict. On the same page:
switching the profile reaches the new proxy, both panes warp a stale map as the Python clients do, and the page's
recording of the run is a session whose views are the cameras the clients fly (``gigan-client --path``) and that
drives ``bench latency --path`` and ``bench storage --sessions-from``. No test bounds a time.

Without Chromium, Playwright or web3d/static/node_modules (``make setup`` runs npm ci) the tests skip and say which
is missing.
"""

from __future__ import annotations

import base64
import json
import math
import re
import shutil
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from baseline_cloudbaking.growth import fill_sessions, session_frames
from bench import latency
from bench.latency import LatencyConfig
from bench.storage_config import StorageConfig
from bench.storage_growth import measure_growth
from bench.viewer_bench import BENCH, SESSION, WebBenchConfig, measure_viewer, open_viewer, record_links
from bench.viewer_present import SCREENSHOT
from gicore import present
from gicore.camera import Camera
from gicore.options import config_dict
from gicore.path_file import read_path_file, scripted_path
from gicore.present.declarations import matches
from gicore.results import Results, read_rows
from gicore.scene import load_scene
from tests.helpers.browser import missing
from tests.helpers.latency_runs import stand_in
from web3d.headless import PAGE_TIMEOUT_S, settle, wait
from web3d.parity import floats

#: Four path frames per profile, a map asked for every two while the view moves; 1 spp maps, prebaked.
CFG = WebBenchConfig(frames=4, every=2, spp=1, timing_runs=2, profiles=("lan", "wan"), timeout_s=300.0)
PARITY_BOUND = 1e-2
#: More than a response's status line and headers: what a proxy carries down besides a map's bytes.
RESPONSE_HEAD_BYTES = 1024
#: How far along the scripted path the warps are compared from its first frame's maps (about 14°: holes behind
#: the lung that the hole filling shows).
STALE_FRAMES = 12


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """bench web's measure on CFG, and on the same page: both canvases with stale maps (warped_by_the_page) and
    the matrices of each recorded view (set through the page's controls); the CSV's rows once the proxies have
    stopped and written their logs."""
    why = missing()
    if why:
        pytest.skip(f"the Web3D viewer cannot run here: {why}")
    out = tmp_path_factory.mktemp("web")
    results = Results("web", out, seed=0, settings=config_dict(CFG))
    with open_viewer(CFG, results) as viewer:
        measure_viewer(viewer, CFG, results)  # what bench web's measure does inside its site
        page = viewer.page
        page.records.pull(page)  # every frame drawn, read as they came (web3d.headless.Records)
        replayed = [f["replay"] for f in page.records.frames]
        farther = scripted_path(load_scene("lung_plane"), STALE_FRAMES + 1, CFG.orbit_frames).to_json()["frames"]
        stale = warped_by_the_page(viewer, viewer.doc["frames"][0], farther[STALE_FRAMES])
        recorded = json.loads((out / SESSION).read_text())["frames"]
        cameras = page.evaluate("frames => frames.map((f) => viewer.setCamera(f.camera))", recorded)
        settle(page)  # the last view's maps landed: every request made has its map
        maps = page.records.maps
    record_links(results, viewer)
    rows = read_rows(results.write())
    present.write_files(BENCH.name, BENCH.parts, rows, out)
    return {"rows": rows, "out": out, "replayed": replayed, "maps": maps, "cameras": cameras, "stale": stale}


def warped_by_the_page(viewer: Any, made: dict[str, Any], shown: dict[str, Any]) -> dict[str, Any]:
    """Both canvases as the page draws path frame ``shown`` with the maps made at path frame ``made`` (settled
    there first; the snapshot is taken as that frame is drawn, before any new map lands), and the stored cloud
    map the pane shows, read from the server by the address the page got with it (the map of ``made``'s view, or
    an earlier one where the GI period sent no request there)."""
    page = viewer.page
    drawn = page.evaluate("viewer.frames.count")
    page.evaluate("f => { viewer.setCamera(f.camera); viewer.setLight(f.light); }", made)
    wait(page, "n => viewer.frames.count > n", drawn)
    settle(page)
    doc = viewer.doc | {"frames": [shown]}
    snapshot = page.evaluate("doc => viewer.replay(doc).then(() => viewer.snapshot())", doc)
    [server] = [line for line in viewer.children if line.startswith("cloudbaking-server, given store ")]
    url = re.search(r": (http://\S+) \(pid", server)[1]
    assert re.fullmatch(r"/v1/maps/[0-9a-f]{64}", snapshot["cloud"]["map"] or ""), snapshot["cloud"]["map"]
    answer = httpx.get(f"{url}{snapshot['cloud']['map']}", timeout=PAGE_TIMEOUT_S)
    assert answer.status_code == 200, answer.text[:200]
    return {"snapshot": snapshot, "payload": answer.content, "shown": shown, "parity": page.evaluate("viewer.parity")}


def rows_of(rows: list[dict], metric: str, stat: str | None = None, **config: Any) -> list[dict]:
    return [r for r in rows if matches(r, metric, stat, **config)]


@pytest.mark.slow
def test_the_path_replays_through_the_pages_controls_once_per_profile(run) -> None:
    replayed = [f for f in run["replayed"] if f is not None]
    assert replayed == [*range(CFG.frames)] * len(CFG.profiles)  # one path frame per drawn frame, in order
    profiles = [m["profile"] for m in run["maps"] if m["system"] == "cloud_baking"]
    assert profiles == sorted(profiles, key=CFG.profiles.index) and set(profiles) == set(CFG.profiles)
    session = read_path_file(run["out"] / SESSION, load_scene("lung_plane"))  # the page's recording: a path file
    assert len(session.frames) == len(run["replayed"])  # one per frame drawn


def test_each_system_and_profile_reports_frame_times_map_age_perceived_latency_and_stages(run) -> None:
    rows = run["rows"]
    for profile in CFG.profiles:
        for system in ("gigan", "cloud_baking"):
            at = {"system": system, "profile": profile}
            mine = [r for r in rows if r["system"] == system and r["config"].get("profile") == profile]
            all_frames = rows_of(mine, "frame_ms", "n", phase="all")
            assert all_frames and all_frames[0]["value"] >= CFG.frames, at
            phases = {r["config"]["phase"] for r in rows_of(mine, "frame_ms", "median")}
            assert {"all", "landing"} <= phases and phases <= {"all", "idle", "in_flight", "landing"}, at
            during = rows_of(mine, "frames_during_map", "map")
            assert during and all(r["value"] >= 1 for r in during), at  # no map is joined in the frame that asked
            assert len(during) == rows_of(mine, "total", "n")[0]["value"], at
            assert rows_of(mine, "map_age_ms", "median") and rows_of(mine, "map_age_frames", "p95"), at
            assert rows_of(mine, "perceived_ms", "median") or rows_of(mine, "censored")[0]["value"] > 0, at
        checks = rows_of(rows, "frame_ms", "target_met", profile=profile) + rows_of(
            rows, "frames_during_map", "target_met", profile=profile
        )
        assert len(checks) == 2 and all(r["value"] in (0.0, 1.0) or math.isnan(r["value"]) for r in checks)
        assert rows_of(rows, "hit_rate", profile=profile)[0]["value"] == 1.0  # the prebaked store serves each ask
        assert rows_of(rows, "total_ratio", profile=profile)[0]["value"] > 0
    text = (run["out"] / "web.md").read_text()
    assert "| GIGAN | wan |" in text and "| cloud baking | wan |" in text and "fewest >= 1" in text
    assert (run["out"] / SCREENSHOT).stat().st_size > 20_000  # a PNG of two lit canvases and their HUDs


def test_browser_prediction_matches_gimodel_predict_and_both_inference_times_are_recorded(run) -> None:
    rows = run["rows"]
    assert 0.0 <= rows_of(rows, "parity_max_abs_diff")[0]["value"] <= PARITY_BOUND
    runs = {r["config"]["runtime"]: r["value"] for r in rows_of(rows, "inference_run", "n")}
    assert runs == {"onnxruntime-web": CFG.timing_runs, "onnxruntime-python": CFG.timing_runs}
    ratio = rows_of(rows, "inference_ratio")[0]["value"]
    assert math.isfinite(ratio) and ratio > 0


def test_both_canvases_show_the_scene_lit_by_gi(run) -> None:
    for system in ("gigan", "cloud_baking"):
        value = {r["metric"]: r["value"] for r in run["rows"] if r["system"] == system}
        # the lung and the ground plane cover most of the frame; the sky above the plane is black
        assert value["canvas_lit"] > 0.4, system
        # tau = 0: the canvas is the warped GI map, whose indirect light the DI alone lacks
        assert value["canvas_vs_di"] > 0.01, system


def test_the_pages_webgl2_passes_match_glrenderers(run) -> None:
    """The shaders ported to WebGL2 (SwiftShader) against the GLSL they come from (Mesa through moderngl)."""
    port = {r["metric"].removeprefix("port_"): r["value"] for r in run["rows"] if r["metric"].startswith("port_")}
    if not port:
        pytest.skip("no OpenGL context for GLRenderer here (make setup installs Mesa's EGL when run as root)")
    assert port["coverage_mismatch"] <= 1e-3  # a few silhouette pixels rasterise differently
    for buffer in ("di", "albedo", "normal", "depth"):
        assert port[f"{buffer}_rel_diff"] <= 1e-2, (buffer, port)


def test_the_pages_warps_are_the_python_clients_on_the_same_maps(run) -> None:
    """Path frame 0's maps drawn at path frame STALE_FRAMES's view: each canvas against the Python client's warp of
    the same map to the same view (gigan_local.warp on the page's own GIGAN map, baseline_cloudbaking.warp on the
    server's cloud map), tone-mapped; the page's raster and rounding differ from GLRenderer's on a few pixels."""
    from baseline_cloudbaking.protocol import decode_payload
    from baseline_cloudbaking.warp import PixelWarp
    from gicore.gi_map import GIMap
    from gicore.gl import GLRenderer, RasterUnavailable
    from gicore.tonemap import inverse_tonemap, tonemap
    from gigan_local.warp import GITexture, StructureAwareWarp

    stale, parity = run["stale"], run["stale"]["parity"]
    n = int(parity["resolution"])
    try:
        renderer = GLRenderer(load_scene("lung_plane"), n, lod=0)
    except RasterUnavailable:
        pytest.skip("no OpenGL context for GLRenderer here (make setup installs Mesa's EGL when run as root)")
    c, light = stale["shown"]["camera"], tuple(stale["shown"]["light"])
    local = Camera(c["eye"], c["target"], c["up"], c["fov"], c["near"], c["far"], width=n, height=n)
    g = parity["camera"]  # the warm-up map, at the page's first view: path frame 0's
    gi_camera = Camera(g["eye"], g["target"], fov=g["fov"], near=g["near"], far=g["far"], width=n, height=n)
    radiance = inverse_tonemap(floats(parity["display"], n, 3))
    depth, di_gi = floats(parity["depth"], n, 4)[::-1, :, 0], floats(parity["di"], n, 4)[::-1, :, :3]
    warp = StructureAwareWarp(renderer)
    warp.bind_texture(GITexture.build(gi_camera, radiance, depth, np.maximum(radiance - di_gi, 0.0)))
    python = {"gigan": warp.warp(local, *renderer.render_di_raster(local, light, raster="uv"))[0]}
    payload = decode_payload(stale["payload"])
    pixel = PixelWarp()
    pixel.bind(GIMap(payload.camera, payload.gi, payload.depth, payload.di))
    python["cloud"] = pixel.warp(local, *renderer.render_di_raster(local, light, raster="mask"))[0]
    for system, image in python.items():
        shown = np.frombuffer(base64.b64decode(stale["snapshot"][system]["canvas"]), np.uint8).reshape(n, n, 4)
        diff = np.abs(shown[::-1, :, :3] / 255.0 - np.rint(tonemap(image) * 255.0) / 255.0).max(axis=-1)
        assert diff.mean() <= 1 / 255 and (diff > 16 / 255).mean() <= 5e-3, (
            system,
            diff.mean(),
            (diff > 16 / 255).mean(),
        )


def test_switching_the_profile_reaches_the_new_proxy(run) -> None:
    """Each profile's proxy carried down the maps the page got through that profile and no other's: its chunk log
    counts them, and at most a response head's worth more per request."""
    for profile in CFG.profiles:
        mine = [m["bytes"] for m in run["maps"] if m.get("profile") == profile]
        link = rows_of(run["rows"], "link_bytes_down", profile=profile)[0]["value"]
        assert mine and sum(mine) <= link < sum(mine) + RESPONSE_HEAD_BYTES * len(mine), (profile, link, mine)


def test_the_recorded_session_flies_the_clients_through_the_same_views(run) -> None:
    """The page's recording read as the clients read ``--path`` (gicore.path_file.flown_path reads it with
    read_path_file): each recorded view's matrices, set through the page's controls, are the camera the clients fly
    there. gigan-client flying a recorded-style path file and writing back the same one is
    tests/bench/test_path_runs.py's."""
    flown = read_path_file(run["out"] / SESSION, load_scene("lung_plane"))
    for doc, waypoint in zip(run["cameras"], flown.frames, strict=True):
        cam: Camera = waypoint.camera
        for name, matrix in (("view", cam.view()), ("proj", cam.proj()), ("view_proj", cam.view_proj())):
            page_matrix = np.asarray(doc[name]).reshape(4, 4).T  # column-major
            np.testing.assert_allclose(page_matrix, matrix, rtol=0, atol=1e-6, err_msg=name)


def test_the_recorded_session_drives_bench_latency_and_bench_storage(
    run, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """bench latency's processes are stood in for (what is checked is what each client is told); bench storage's
    growth law runs on the session for real, at 16 pixels."""
    session = run["out"] / SESSION
    frames = len(read_path_file(session, load_scene("lung_plane")).frames)
    told = stand_in(monkeypatch)
    cfg = LatencyConfig(
        profiles=("lan",), resolution=16, path=session, renderers=("mitsuba",), prefetch_in_flight=0, alone=False
    )
    latency.measure(cfg, Results("latency", tmp_path / "latency", 0))
    assert told.argvs and all(argv[argv.index("--path") + 1] == str(session) for argv in told.argvs)
    assert told.recorded["cfg"].frames == frames and all(c.frames == frames for c in told.asked)

    folder = tmp_path / "sessions"
    folder.mkdir()
    shutil.copy(session, folder / "session.json")
    spec = load_scene("lung_plane")
    cfg = StorageConfig(scenes=("lung_plane",), resolutions=(16,), codecs=("jpeg",), spp=1, growth_samples=1,
                        capacity_samples=10, paper_resolution=16, sessions_from=folder,
                        map_cache=tmp_path / "maps")  # fmt: skip
    res = Results("storage", tmp_path / "storage", 0)
    measure_growth(cfg, res, "lung_plane", {"fp16": 10_000}, {})
    rows = read_rows(res.write())
    flown = [read_path_file(folder / "session.json", spec)]
    expected = fill_sessions(session_frames(spec, flown, cfg.light_cell, spec.camera.gi_fov), cfg.tolerance).entries
    curve = [r["value"] for r in rows if r["metric"] == "growth_entries" and r["config"]["tolerance"] == "store"]
    assert curve == list(expected) and len(curve) == 1
    [store] = [r for r in rows if r["metric"] == "saturation_sessions" and r["config"]["tolerance"] == "store"]
    assert store["config"]["sessions_run"] == 1 and store["config"]["session_frames"] == frames
