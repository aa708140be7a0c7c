"""The Web3D viewer in headless Chromium (SwiftShader WebGL2), both systems against a real cloudbaking-server
behind network-sim proxy: the page autoplays the scripted path's first frames (``?autoplay=1&frames=N``) as bench
web measures it, both canvases show the scene lit by their GI (not blank, not the DI alone), the HUD's numbers are
the CSV's, and the browser's prediction matches GIModel.predict.

Without Chromium, Playwright or web3d/static/node_modules (``make setup`` runs npm ci) the tests skip and say which
is missing.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from bench.viewer_bench import SCREENSHOT, Reference, WebBenchConfig, canvas_stats, record, viewer_site
from gicore.options import config_dict
from gicore.results import Results, read_rows
from tests.helpers.browser import missing, viewer_page, wait

#: Both systems ask for a map at frame 0, and at frame 2 when the first has landed (the page lets the maps in
#: flight land before it is done); a cold store: the server path-traces each at 2 spp.
CFG = WebBenchConfig(frames=3, every=2, spp=2, timing_runs=2, store="cold", profile="lan", timeout_s=240.0)
PARITY_BOUND = 1e-2


def autoplay(url: str, screenshot: Path, reference: Callable[[dict[str, Any]], Callable[[], float]]) -> dict:
    """bench web's measurement of the page: its autoplay of CFG.frames frames, a screenshot, ``session.run`` timed
    alternately in the page and in Python (``reference(viewer)``: one Python run per call, seconds), the last
    frame's snapshot and the HUD's text; returns what ``window.viewer`` holds with those."""
    with viewer_page(url, f"autoplay=1&frames={CFG.frames}") as page:
        wait(page, "window.viewer.done", timeout_s=CFG.timeout_s)
        data = page.evaluate("window.viewer")
        page.locator("#viewer").screenshot(path=str(screenshot))
        python_run = reference(data)
        data["browser_runs_ms"], data["python_runs_ms"] = [], []
        for _ in range(CFG.timing_runs):
            data["browser_runs_ms"].append(page.evaluate("window.viewer.infer()"))
            data["python_runs_ms"].append(python_run() * 1e3)
        data["snapshot"] = page.evaluate("window.viewer.snapshot()")
        data["hud"] = {system: page.inner_text(f"#hud-{system}") for system in ("gigan", "cloud")}
        data["chromium"] = page.context.browser.version
    return data


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    why = missing()
    if why:
        pytest.skip(f"the Web3D viewer cannot run here: {why}")
    out = tmp_path_factory.mktemp("web")
    results = Results("web", out, seed=0, settings=config_dict(CFG))
    reference = Reference(CFG.threads, "lung_plane")
    with viewer_site(CFG, 0, out / "work") as url:
        viewer = autoplay(url, out / SCREENSHOT, reference.check)
    record(results, "lung_plane", CFG, viewer, reference.diff, reference.port)
    rows = read_rows(results.write())
    return {"viewer": viewer, "rows": rows, "diff": reference.diff, "port": reference.port, "out": out}


def test_the_page_plays_its_frames_and_both_canvases_show_the_scene_lit_by_gi(run) -> None:
    viewer = run["viewer"]
    assert viewer["info"]["cross_origin_isolated"] is True  # what lets onnxruntime-web run wasm threads
    # one path frame per drawn frame from the first, then frames that only land the maps in flight
    replayed = [f["replay"] for f in viewer["frames"]]
    assert replayed == [*range(CFG.frames), *[None] * (len(replayed) - CFG.frames)]
    systems = {m["system"] for m in viewer["maps"]}
    assert systems == {"gigan", "cloud_baking"}
    stats = canvas_stats(viewer["snapshot"])
    for system in ("gigan", "cloud"):
        # the lung and the ground plane cover most of the frame; the sky above the plane is black
        assert stats[system]["lit"] > 0.4, (system, stats)
        # tau = 0: the canvas is the warped GI map, whose indirect light the DI alone lacks
        assert stats[system]["vs_di"] > 0.01, (system, stats)
    assert (run["out"] / SCREENSHOT).stat().st_size > 20_000  # a PNG of two lit 256² canvases and their HUDs


def _hud_median(text: str, stage: str) -> float:
    line = next(line for line in text.splitlines() if line.split("\t")[0].strip() == stage)
    return float(re.split(r"\t", line)[2])


def test_the_huds_numbers_land_in_the_csv(run) -> None:
    viewer, rows = run["viewer"], run["rows"]
    for page_system, system in (("gigan", "gigan"), ("cloud", "cloud_baking")):
        maps = [m for m in viewer["maps"] if m["system"] == system]
        mine = [r for r in rows if r["system"] == system and r["stat"] == "map"]
        per_map = {(r["config"]["frame"], r["metric"]): r["value"] for r in mine}
        for m in maps:
            assert per_map[m["frame"], "total"] == pytest.approx(m["total"])
            for stage, value in m["stages"].items():
                if (m["frame"], stage) in per_map:
                    assert per_map[m["frame"], stage] == pytest.approx(value)
        median = next(r["value"] for r in rows if (r["system"], r["metric"], r["stat"]) == (system, "total", "median"))
        assert _hud_median(viewer["hud"][page_system], "total") == pytest.approx(median, abs=0.051)
        assert median > 0
    ratio = next(r["value"] for r in rows if r["metric"] == "total_ratio")
    medians = {r["system"]: r["value"] for r in rows if r["metric"] == "total" and r["stat"] == "median"}
    assert ratio == pytest.approx(medians["cloud_baking"] / medians["gigan"])


def test_browser_prediction_matches_gimodel_predict_and_both_inference_times_are_recorded(run) -> None:
    rows = run["rows"]
    assert 0.0 <= run["diff"]["max"] <= PARITY_BOUND
    assert next(r["value"] for r in rows if r["metric"] == "parity_max_abs_diff") == run["diff"]["max"]
    runs = {r["config"]["runtime"]: r["value"] for r in rows if r["metric"] == "inference_run" and r["stat"] == "n"}
    assert runs == {"onnxruntime-web": CFG.timing_runs, "onnxruntime-python": CFG.timing_runs}
    ratio = next(r["value"] for r in rows if r["metric"] == "inference_ratio")
    assert math.isfinite(ratio) and ratio > 0


def test_the_pages_webgl2_passes_match_glrenderers(run) -> None:
    """The shaders ported to WebGL2 (SwiftShader) against the GLSL they come from (Mesa through moderngl)."""
    port = run["port"]
    if not port:
        pytest.skip("no OpenGL context for GLRenderer here (make setup installs Mesa's EGL when run as root)")
    assert port["coverage_mismatch"] <= 1e-3  # a few silhouette pixels rasterise differently
    for buffer in ("di", "albedo", "normal", "depth"):
        assert port[f"{buffer}_rel_diff"] <= 1e-2, (buffer, port)
    assert {f"port_{k}" for k in port} <= {r["metric"] for r in run["rows"]}
