"""The Web3D page a person drives, in headless Chromium (SwiftShader WebGL2) served by gigan-web's server with a
real cloud-baking server on a cold store (1 spp) behind one network-sim proxy: a drag and a wheel move the camera
and both canvases, frames keep coming while GIGAN's map is computed and a cloud map is decoded (in its worker),
the page's camera matrices are gicore.camera's, recordings are path files the clients read, and the light slider
moves the light and the GI.

GIGAN's network is a stand-in that passes the DI through, at 64 px: what is checked here is the page, not the
network (the shipped model runs in the browser in test_viewer.py, against GIModel.predict). One page serves the
whole module; each test first waits until no map is in flight. Skips, saying why, without Chromium, Playwright or
web3d/static/node_modules.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gicore.camera import Camera
from gicore.options import FRAMES_MAX
from gicore.path_file import read_path_file
from gicore.paths import light_bounds, navigation, outside_navigation
from gicore.scene import SceneSpec, load_scene
from tests.helpers.browser import canvases, missing, wait
from tests.helpers.cloud import passthrough_model
from web3d.headless import served_page

SCENE = "lung_plane"
#: The page's maps and canvases, in pixels: small, as each frame draws both panes in software.
RESOLUTION = 64
#: Path frames a replay plays (small: each frame draws both panes in software).
REPLAYED = 6
#: A canvas has changed when its mean |difference| is above this (0-255): the DI alone moves it by far more.
CHANGED = 1.0
IDLE = "(() => { const f = viewer.frames.last(); return f && !f.gigan.inflight && !(f.cloud && f.cloud.inflight); })()"
#: Frames drawn and maps made so far.
COUNTS = "[viewer.frames.count, viewer.maps.count]"


@pytest.fixture(scope="module")
def spec() -> SceneSpec:
    return load_scene(SCENE)


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Any:
    why = missing()
    if why:
        pytest.skip(f"the Web3D page cannot run here: {why}")
    from web3d.cli import WebConfig, cloud_for, prepare

    work = tmp_path_factory.mktemp("page")
    model = passthrough_model(work / "model", RESOLUTION)
    cfg = WebConfig(scene=SCENE, profiles=("lan",), listen="127.0.0.1:0", assets=work / "assets", spp=1, every=1,
                    model=model)  # fmt: skip
    cloud = cloud_for(cfg, report=lambda line: None)
    site = prepare(cfg, cloud)
    with served_page(site) as (_, page):
        yield page


def settle(page: Any) -> None:
    """Wait until the page has a frame and no map in flight (nothing draws until something changes)."""
    wait(page, IDLE)


def path_frames(page: Any, count: int) -> dict[str, Any]:
    """The exported scripted path (a path file) cut to its first ``count`` frames."""
    doc = page.evaluate("fetch('/assets/path.json').then((r) => r.json())")
    return doc | {"frames": doc["frames"][:count]}


def changed(before: dict[str, np.ndarray], after: dict[str, np.ndarray]) -> dict[str, float]:
    return {k: float(np.abs(after[k].astype(np.float64) - before[k]).mean()) for k in before}


def drawn_after(page: Any, n: int) -> None:
    wait(page, "n => viewer.frames.count > n", n)


@pytest.mark.slow
def test_a_drag_and_a_wheel_move_the_camera_and_both_canvases(page: Any) -> None:
    settle(page)
    cam0, shot0, n = page.evaluate("viewer.camera()"), canvases(page), page.evaluate("viewer.frames.count")
    assert set(shot0) == {"gigan", "cloud"}
    box = page.locator("#gigan").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 150, y + 10, steps=5)
    page.mouse.up()
    drawn_after(page, n)
    settle(page)
    cam1, shot1 = page.evaluate("viewer.camera()"), canvases(page)
    assert math.dist(cam0["eye"], cam1["eye"]) > 0.05  # an orbit: the eye moved round the target
    assert cam1["target"] == pytest.approx(cam0["target"], abs=1e-9)
    assert all(v > CHANGED for v in changed(shot0, shot1).values()), changed(shot0, shot1)

    n = page.evaluate("viewer.frames.count")
    page.mouse.move(x, y)
    page.mouse.wheel(0, -200)  # zoom in
    drawn_after(page, n)
    settle(page)
    cam2, shot2 = page.evaluate("viewer.camera()"), canvases(page)
    assert math.dist(cam2["eye"], cam2["target"]) < math.dist(cam1["eye"], cam1["target"]) - 1e-3
    assert all(v > CHANGED for v in changed(shot1, shot2).values()), changed(shot1, shot2)


def test_the_page_loads_without_a_failed_request(page: Any) -> None:
    """The browser's own requests too (a favicon the page did not name was a 404 on every load)."""
    settle(page)
    assert not [m for m in page.console_errors if "Failed to load resource" in m], page.console_errors


def test_an_arrow_key_pans_noticeably(page: Any, spec: SceneSpec) -> None:
    settle(page)
    pose = path_frames(page, 1)["frames"][0]["camera"]
    before = page.evaluate("p => viewer.setCamera(p)", {"eye": pose["eye"], "target": pose["target"]})
    n = page.evaluate("viewer.frames.count")
    page.locator("#stage").press("ArrowLeft")
    drawn_after(page, n)
    after = page.evaluate("viewer.camera()")
    # a pan moves the eye sideways: by 3 % of the orbit's radius at least (OrbitControls' default moved it 1 %)
    assert math.dist(before["eye"], after["eye"]) > 0.03 * spec.camera.radius, (before["eye"], after["eye"])


def test_a_key_on_a_light_slider_moves_the_light_a_twentieth_of_its_range(page: Any, spec: SceneSpec) -> None:
    settle(page)
    low, high = light_bounds(spec)
    middle = [(lo + hi) / 2 for lo, hi in zip(low, high)]
    page.evaluate("l => viewer.setLight(l)", middle)
    page.locator("#light-x").press("ArrowRight")
    assert page.evaluate("viewer.light()")[0] == pytest.approx(middle[0] + (high[0] - low[0]) / 20)
    page.locator("#light-y").press("ArrowDown")
    assert page.evaluate("viewer.light()")[1] == pytest.approx(middle[1] - (high[1] - low[1]) / 20)


def test_stop_clears_the_recording_mark_at_once(page: Any) -> None:
    """Stop is a click that changes no view: no frame may come to redraw the HUD, so the click does."""
    settle(page)
    page.evaluate("viewer.record(true)")
    assert "● recording" in page.locator("#status").text_content()
    with page.expect_download():
        status = page.evaluate("""() => {
          document.getElementById("record").click();
          return document.getElementById("status").textContent;
        }""")
    assert "recording" not in status, status


def test_the_shadow_setups_kept_are_bounded_dropping_the_least_recently_used(page: Any) -> None:
    size, oldest, used, newest = page.evaluate("""async () => {
      const { ShadowSetups } = await import("/js/light.js");
      const setups = new ShadowSetups();
      for (let i = 0; i < 4096; i++) setups.remember(`0,0,${i}`, { i });
      setups.get([0, 0, 0]); // used: now the most recent
      for (let i = 4096; i < 5000; i++) setups.remember(`0,0,${i}`, { i });
      return [setups.cache.size, setups.cache.has("0,0,1"), setups.cache.has("0,0,0"), setups.cache.has("0,0,4999")];
    }""")
    assert (size, oldest, used, newest) == (4096, False, True, True)


def test_the_pages_histories_are_bounded_and_read_by_index(page: Any) -> None:
    """viewer.frames and viewer.maps keep their last records (a driver reads what is new by index); asking for one
    dropped is an error that says so."""
    kept, since, recent, last, error = page.evaluate("""async () => {
      const { History } = await import("/js/history.js");
      const h = new History("frames", 4);
      for (let i = 0; i < 10; i++) h.push({ i });
      let error = null;
      try { h.since(5); } catch (e) { error = e.message; }
      return [[h.count, h.first], h.since(7).map((r) => r.i), h.recent(2).map((r) => r.i), h.last().i, error];
    }""")
    assert (kept, since, recent, last) == ([10, 6], [7, 8, 9], [8, 9], 9)
    assert error == "frames 5 to 5 are no longer kept (the page keeps the last 4): read them more often"
    capacities = page.evaluate("[viewer.frames.capacity, viewer.maps.capacity]")
    assert capacities[0] >= 1000 and capacities[1] >= 100, capacities
    assert page.evaluate("viewer.frames.since(viewer.frames.count)") == []


def test_a_recording_stops_at_the_most_frames_a_path_file_holds_and_says_so(page: Any) -> None:
    assert page.evaluate("viewer.config.record_frames_max") == FRAMES_MAX
    held, full, words = page.evaluate("""async () => {
      const { Recorder } = await import("/js/record.js");
      const camera = { eye: [0, 0, 1], target: [0, 0, 0], up: [0, 1, 0], fov: 60, near: 0.1, far: 10 };
      const recorder = new Recorder("lung_plane", 3);
      recorder.set(true);
      for (let t = 0; t < 5; t++) recorder.push(t, camera, [0, 1, 0]);
      return [recorder.doc().frames.map((f) => f.t_ms), recorder.full, recorder.describe()];
    }""")
    assert (held, full) == ([0, 1, 2], True)
    assert words == "● recording full at 3 frames, the most a path file holds: Stop downloads it"


def test_the_hud_shows_each_panes_stages_as_text(page: Any) -> None:
    settle(page)
    for pane in ("gigan", "cloud"):
        rows = page.locator(f"#hud-{pane} tr").all_text_contents()
        assert rows[0] == "stage (ms)lastmedian" and rows[-2].startswith("total"), rows
        assert re.fullmatch(r"maps\d+( \(medians of the last \d+\))?", rows[-1]), rows
        assert page.locator(f"#hud-{pane} b").all_text_contents() == ["total"]
        assert re.match(r"frame \d+\.\d ms · ", page.locator(f"#live-{pane}").text_content()), pane


def test_frames_keep_coming_while_a_gigan_map_is_computed_and_a_cloud_map_decoded(page: Any) -> None:
    settle(page)
    start, maps0 = page.evaluate(COUNTS)
    page.evaluate("doc => viewer.replay(doc)", path_frames(page, REPLAYED))
    settle(page)
    frames = page.evaluate("i => viewer.frames.since(i)", start)
    maps = page.evaluate("i => viewer.maps.since(i)", maps0)
    cloud = [m for m in maps if m["system"] == "cloud_baking" and m["frame"] >= start]
    assert cloud and all(m["decoding"]["in"] == "DedicatedWorkerGlobalScope" for m in cloud), cloud
    assert all(0 < m["stages"]["decode_work"] <= m["stages"]["decode"] for m in cloud), cloud
    assert [f["replay"] for f in frames[:REPLAYED]] == list(range(REPLAYED))  # one path frame per drawn frame
    for system, pane in (("gigan", "gigan"), ("cloud_baking", "cloud")):
        first = min(m["frame"] for m in maps if m["system"] == system and m["frame"] >= start)
        # the frames drawn while that map was made (GIGAN: computed; cloud: fetched and decoded in the worker):
        # from the one that sent its request (it drew with the map before, not waiting for this one) to the one
        # before it was shown; all of them, and at least that one. Whether a frame's drawing overlaps the worker's
        # decode in time depends on the machine's speed, so the test asks only that frames kept coming.
        during = []
        for f in frames[first - start :]:
            if f[pane]["map_frame"] == first:
                break
            during.append(f)
        assert during and all(f[pane]["inflight"] and f[pane]["map_frame"] < first for f in during), (system, frames)
        assert len(during) < len(frames) - (first - start)  # and it was shown after


def test_the_pages_camera_matrices_are_gicore_cameras(page: Any, spec: SceneSpec) -> None:
    nav = navigation(spec)
    rng = np.random.default_rng(0)
    tx, ty, tz = nav["target"]
    for _ in range(5):
        r, a, h = rng.uniform(*nav["radius"]), rng.uniform(0, 2 * math.pi), rng.uniform(*nav["height"])
        eye = [tx + r * math.sin(a), h, tz + r * math.cos(a)]
        target = [tx + rng.uniform(-1, 1) * nav["target_wobble"], ty + rng.uniform(-1, 1) * nav["target_wobble"], tz]
        cam = page.evaluate("p => viewer.setCamera(p)", {"eye": eye, "target": target})
        assert cam["eye"] == eye and cam["target"] == target  # inside the envelope: as given
        assert (cam["fov"], cam["near"], cam["far"]) == (spec.camera.local_fov, spec.camera.near, spec.camera.far)
        ref = Camera(cam["eye"], cam["target"], cam["up"], cam["fov"], cam["near"], cam["far"])
        for name, matrix in (("view", ref.view()), ("proj", ref.proj()), ("view_proj", ref.view_proj())):
            page_matrix = np.asarray(cam[name]).reshape(4, 4).T  # column-major
            np.testing.assert_allclose(page_matrix, matrix, rtol=0, atol=1e-6, err_msg=name)
    far = page.evaluate("p => viewer.setCamera(p)", {"eye": [10.0, 10.0, -10.0], "target": [1.0, 2.0, 3.0]})
    assert outside_navigation(nav, far["eye"], 1e-9) is None  # clamped into the envelope
    assert far["target"] == pytest.approx([tx + nav["target_wobble"], ty + nav["target_wobble"], tz])


def test_a_recorded_replay_is_a_path_file_of_the_cameras_and_lights_replayed(
    page: Any, spec: SceneSpec, tmp_path: Path
) -> None:
    settle(page)
    doc = path_frames(page, REPLAYED)
    page.evaluate("viewer.record(true)")
    page.evaluate("doc => viewer.replay(doc)", doc)
    page.evaluate("viewer.record(false)")
    recorded = page.evaluate("viewer.recording()")
    (tmp_path / "session.json").write_text(json.dumps(recorded))
    flown = read_path_file(tmp_path / "session.json", spec)
    assert len(flown.frames) == len(recorded["frames"]) >= REPLAYED
    for got, want in zip(flown.frames, doc["frames"]):  # the replay's frames first, exactly
        assert list(got.camera.origin) == want["camera"]["eye"]
        assert list(got.camera.target) == want["camera"]["target"]
        assert list(got.light) == want["light"]
    assert recorded["frames"][0]["t_ms"] == 0.0


def test_the_record_button_downloads_the_session(page: Any, spec: SceneSpec, tmp_path: Path) -> None:
    settle(page)
    page.click("#record")
    n = page.evaluate("viewer.frames.count")
    here = page.evaluate("viewer.camera()")["eye"]  # a pose it is not at: a camera set where it is draws nothing
    pose = next(f["camera"] for f in path_frames(page, 2)["frames"] if f["camera"]["eye"] != here)
    page.evaluate("p => viewer.setCamera(p)", {"eye": pose["eye"], "target": pose["target"]})
    drawn_after(page, n)
    with page.expect_download() as download:
        page.click("#record")
    name = download.value.suggested_filename
    assert re.fullmatch(r"session-[0-9T-]+Z\.json", name), name
    download.value.save_as(tmp_path / name)
    flown = read_path_file(tmp_path / name, spec)
    assert flown.frames and list(flown.frames[-1].camera.origin) == pose["eye"]


def test_the_light_slider_moves_the_light_and_the_gi(page: Any) -> None:
    settle(page)
    light0, shot0 = page.evaluate("viewer.light()"), canvases(page)
    start, maps0 = page.evaluate(COUNTS)
    page.evaluate("viewer.record(true)")
    page.locator("#light-x").press("End")  # a person's keys on the slider: its largest x
    light1 = page.evaluate("viewer.light()")
    assert light1[0] > light0[0] and light1[1:] == light0[1:]
    wait(page, "x => viewer.recording().frames.some((f) => f.light[0] === x)", light1[0])  # drawn with it
    settle(page)
    page.evaluate("viewer.record(false)")
    assert all(v > CHANGED for v in changed(shot0, canvases(page)).values())
    new = page.evaluate("i => viewer.maps.since(i)", maps0)
    assert any(m["system"] == "gigan" and m["frame"] >= start for m in new)  # new GI
