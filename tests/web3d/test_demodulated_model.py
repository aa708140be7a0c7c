"""An albedo-demodulated model in the Web3D page (headless Chromium, SwiftShader WebGL2): the page's encoding
divides the DI by the albedo divisor and its decoding multiplies the output by it, as GIModel.predict does, so the
page's decoded GI map matches Python's on the page's own G-buffers. The model is a real ONNX pass-through of the DI
channels, whose map is the DI again only when both divisions agree.

Skips, saying why, without Chromium, Playwright or web3d/static/node_modules.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.viewer_bench import WebBenchConfig, measure_viewer, open_viewer
from gicore.options import config_dict
from gicore.results import Results, read_rows
from tests.helpers.browser import missing
from tests.helpers.cloud import passthrough_model

PARITY_BOUND = 1e-2


def test_the_page_multiplies_the_albedo_back_as_python_does(tmp_path: Path) -> None:
    why = missing()
    if why:
        pytest.skip(f"the Web3D viewer cannot run here: {why}")
    model = passthrough_model(tmp_path / "model", 256, albedo_floor=0.05)
    cfg = WebBenchConfig(frames=2, every=2, spp=1, timing_runs=1, profiles=("lan",), model=model, timeout_s=300.0)
    results = Results("web", tmp_path / "out", seed=0, settings=config_dict(cfg))
    with open_viewer(cfg, results) as viewer:
        measure_viewer(viewer, cfg, results)
    rows = read_rows(results.write())
    [parity] = [r for r in rows if r["metric"] == "parity_max_abs_diff"]
    assert 0.0 <= parity["value"] <= PARITY_BOUND
