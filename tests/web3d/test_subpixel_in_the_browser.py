"""The sub-pixel graph (gigan_local.subpixel) in onnxruntime-web: its wasm and WebGPU back ends (SwiftShader's
software adapter) compute what onnxruntime computes in Python. onnxruntime-web 1.30's WebGPU convolution gets
2x2 kernels padded on one side wrong on a 2x2 input, which a rewrite of the U-Net's innermost layers hit (max
|error| 0.12 on the shipped model's output); this test runs up layers on inputs of 2 to 32 px.

Skips, saying why, without Chromium, Playwright or web3d/static/node_modules.
"""

from __future__ import annotations

import io
import threading
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from gigan_local import subpixel as sp
from gigan_local.subpixel import subpixel_upsampling
from tests.helpers.browser import SWIFTSHADER_WEBGPU, chromium, missing
from web3d.serve import WEB_DIR

LAYERS, CHANNELS = 5, 16
PAGE = """<html><body><script type="module">
import * as ort from "/ort/ort.all.min.mjs";
ort.env.wasm.wasmPaths = "/ort/";
ort.env.wasm.numThreads = 1;
window.predict = async (backend, input, shape) => {
  const model = await (await fetch("/model.onnx")).arrayBuffer();
  const session = await ort.InferenceSession.create(model, { executionProviders: [backend] });
  const result = await session.run({ input: new ort.Tensor("float32", Float32Array.from(input), shape) });
  return Array.from(result.output.data);
};
window.ready = true;
</script></body></html>"""


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory):
    """A folder served on loopback (the page, onnxruntime-web's files and the rewritten model) open in headless
    Chromium; and the model's input and onnxruntime's output on it."""
    why = missing()
    if why:
        pytest.skip(f"onnxruntime-web cannot run here: {why}")
    root = tmp_path_factory.mktemp("subpixel_web")
    x, expected = write_model(root)
    (root / "index.html").write_text(PAGE)
    (root / "ort").symlink_to(WEB_DIR / "node_modules" / "onnxruntime-web" / "dist")
    handler = partial(SimpleHTTPRequestHandler, directory=str(root))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        with chromium(SWIFTSHADER_WEBGPU) as browser:  # one browser and page for both back ends
            page = browser.new_page()
            page.goto(f"http://127.0.0.1:{server.server_port}/index.html")
            page.wait_for_function("window.ready === true")
            yield page, x, expected
    finally:
        server.shutdown()
        server.server_close()


def write_model(root: Path) -> tuple[np.ndarray, np.ndarray]:
    """The rewritten decoder as ``root/model.onnx``; an input and onnxruntime's output on it."""
    torch.manual_seed(0)
    layers: list[torch.nn.Module] = []
    for i in range(LAYERS):  # a decoder from a 2x2 input: up layers on inputs of 2, 4, ..., 32 px
        layers += [torch.nn.Upsample(scale_factor=2, mode="nearest"), torch.nn.Conv2d(CHANNELS, CHANNELS, 3, padding=1)]
        layers += [torch.nn.ReLU()] if i < LAYERS - 1 else []
    buffer = io.BytesIO()
    torch.onnx.export(torch.nn.Sequential(*layers).eval(), (torch.zeros(1, CHANNELS, 2, 2),), buffer, dynamo=False,
                      opset_version=17, input_names=["input"], output_names=["output"])  # fmt: skip
    model, rewritten = subpixel_upsampling(onnx.load_from_string(buffer.getvalue()))
    assert rewritten == sum(2 * 2**i >= sp.MIN_SIDE for i in range(LAYERS))
    (root / "model.onnx").write_bytes(model.SerializeToString())
    x = np.random.default_rng(1).uniform(-1, 1, (1, CHANNELS, 2, 2)).astype(np.float32)
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return x, session.run(None, {"input": x})[0]


@pytest.mark.parametrize("backend", ["wasm", "webgpu"])
def test_onnxruntime_web_computes_the_sub_pixel_graph_as_python_does(site, backend: str) -> None:
    page, x, expected = site
    if backend == "webgpu" and not page.evaluate("async () => !!(await navigator.gpu?.requestAdapter())"):
        pytest.skip("this Chromium offers no WebGPU adapter, not even SwiftShader's")
    out = page.evaluate("([b, x, s]) => window.predict(b, x, s)", [backend, x.ravel().tolist(), list(x.shape)])
    error = np.abs(np.asarray(out, np.float32).reshape(expected.shape) - expected).max()
    assert error < 1e-5 * np.abs(expected).max()
