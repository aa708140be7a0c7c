"""gigan_local.subpixel: a resize U-Net's up-sampling as phase convolutions computes what torch computes."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from typer.testing import CliRunner

from gicore.error_policy import UserError
from gigan_local.config import NetworkConfig
from gigan_local.export import FILES, fp16_weights, rewrite_export
from gigan_local.inference import DEFAULT_MODEL, MODEL_JSON
from gigan_local.networks import define_G
from gigan_local.rewrite_cli import app
from gigan_local.subpixel import GRAPH_NAME, MIN_SIDE, phase_taps, subpixel_upsampling
from tests.helpers.cli import TIMEOUT_S, Outcome, check_user_error, snapshot


def _onnx(net: torch.nn.Module, shape: tuple[int, ...]) -> onnx.ModelProto:
    buffer = io.BytesIO()
    net.eval()
    torch.onnx.export(
        net, (torch.zeros(shape),), buffer, dynamo=False, opset_version=17, input_names=["input"],
        output_names=["output"], dynamic_axes={"input": {0: "batch"}, "output": {0: "batch"}},
    )  # fmt: skip
    return onnx.load_from_string(buffer.getvalue())


def _run(model: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    return ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {"input": x})[
        0
    ]


def _ops(model: onnx.ModelProto) -> Counter:
    return Counter(node.op_type for node in model.graph.node)


@pytest.mark.parametrize("out_channels", [3, 16, 24])
def test_one_layer_matches_resize_then_conv_at_every_border(out_channels):
    """A non-square input, both phase forms (one 3x3 conv below 16 channels, four 2x2 ones from 16)."""
    torch.manual_seed(0)
    layer = torch.nn.Sequential(
        torch.nn.Upsample(scale_factor=2, mode="nearest"), torch.nn.Conv2d(5, out_channels, 3, padding=1)
    )
    x = np.random.default_rng(1).normal(size=(2, 5, 9, 11)).astype(np.float32)
    with torch.no_grad():
        ref = layer(torch.from_numpy(x)).numpy()
    model, n = subpixel_upsampling(_onnx(layer, (1, 5, 9, 11)))
    assert n == 1
    assert _ops(model)["Resize"] == 0 and _ops(model)["DepthToSpace"] == 1
    assert _ops(model)["Conv"] == (1 if out_channels < 16 else 4)
    out = _run(model, x)
    assert out.shape == ref.shape
    assert np.abs(out - ref).max() < 1e-5


def test_phase_taps_sum_the_kernel_taps_that_land_on_one_input_pixel():
    w = np.random.default_rng(2).normal(size=(3, 3))
    for dy in (0, 1):
        for dx in (0, 1):
            full = (w.reshape(1, 9) @ phase_taps(dy, dx, 3)).reshape(3, 3)
            window = np.zeros((3, 3), bool)
            window[dy : dy + 2, dx : dx + 2] = True
            assert np.all(full[~window] == 0)
            assert np.allclose(full[window], (w.reshape(1, 9) @ phase_taps(dy, dx, 2)).ravel())
            assert np.isclose(full.sum(), w.sum())  # every tap lands once
    top_left = (w.reshape(1, 9) @ phase_taps(0, 0, 2)).reshape(2, 2)
    # output pixel (0, 0): kernel row 0 reads input row -1, rows 1 and 2 read row 0 (the resize repeats it)
    assert np.allclose(top_left, [[w[0, 0], w[0, 1:].sum()], [w[1:, 0].sum(), w[1:, 1:].sum()]])


def test_a_layer_on_a_small_input_is_left_as_it_is():
    layer = torch.nn.Sequential(torch.nn.Upsample(scale_factor=2, mode="nearest"), torch.nn.Conv2d(5, 16, 3, padding=1))
    model, n = subpixel_upsampling(_onnx(layer, (1, 5, MIN_SIDE - 1, 16)))
    assert n == 0 and _ops(model)["Resize"] == 1


def test_resize_unet_graph_is_rewritten_from_the_minimum_side_and_exact():
    torch.manual_seed(3)
    cfg = NetworkConfig(name="unet", in_channels=10, out_channels=3, width=8, n_down=5, upsample="resize")
    net = define_G(cfg).eval()
    x = np.random.default_rng(4).uniform(-1, 1, (2, 10, 64, 64)).astype(np.float32)
    with torch.no_grad():
        ref = net(torch.from_numpy(x)).numpy()
    model, n = subpixel_upsampling(_onnx(net, (1, 10, 64, 64)))
    assert n == 3  # up layers on 8, 16 and 32 px inputs; those on 2 and 4 px keep their resize
    ops = _ops(model)
    assert ops["Resize"] == 2 and ops["DepthToSpace"] == 3 and ops["Constant"] == 2
    assert np.abs(_run(model, x) - ref).max() < 1e-5


def test_transposed_unet_is_left_as_it_is():
    cfg = NetworkConfig(name="unet", in_channels=10, out_channels=3, width=8, n_down=5, upsample="transposed")
    original = _onnx(define_G(cfg), (1, 10, 32, 32))
    model, n = subpixel_upsampling(original)
    assert n == 0
    assert _ops(model) == _ops(original)


def _resize_graph_export(folder: Path) -> None:
    """An export folder as gigan-export wrote it before the rewrite (resize graph, no ``graph`` entry)."""
    torch.manual_seed(5)
    cfg = NetworkConfig(name="unet", in_channels=10, out_channels=3, width=8, n_down=5, upsample="resize")
    model = _onnx(define_G(cfg), (1, 10, 32, 32))
    folder.mkdir()
    (folder / FILES["fp32"]).write_bytes(model.SerializeToString())
    (folder / FILES["fp16"]).write_bytes(fp16_weights(model).SerializeToString())
    doc = json.loads((DEFAULT_MODEL.parent / MODEL_JSON).read_text())
    doc.pop("graph", None)
    doc.pop("graph_rewrite", None)
    doc.update(resolution=32, in_channels=10, network=cfg.to_dict())
    (folder / MODEL_JSON).write_text(json.dumps(doc))


def test_rewrite_export_rewrites_both_files_in_place_and_only_once(tmp_path):
    folder = tmp_path / "model"
    _resize_graph_export(folder)
    x = np.random.default_rng(6).uniform(-1, 1, (1, 10, 32, 32)).astype(np.float32)
    before = {k: _run(onnx.load(str(folder / f)), x) for k, f in FILES.items() if k != "int8"}
    result = CliRunner().invoke(app, [str(folder)])
    assert result.exit_code == 0, result.output
    doc = json.loads((folder / MODEL_JSON).read_text())
    assert doc["graph"] == GRAPH_NAME and doc["graph_rewrite"]["layers"] == 2  # inputs of 8 and 16 px
    for k, ref in before.items():
        model = onnx.load(str(folder / FILES[k]))
        assert _ops(model)["DepthToSpace"] == 2
        assert np.abs(_run(model, x) - ref).max() < (1e-5 if k == "fp32" else 2e-3)
        assert doc["graph_rewrite"]["max_abs_diff_vs_resize_graph"][k] < (1e-5 if k == "fp32" else 2e-3)
    with pytest.raises(UserError, match="already rewritten"):
        rewrite_export(folder)


def test_rewrite_export_refuses_a_folder_without_a_model(tmp_path):
    with pytest.raises(UserError, match="model_fp32.onnx is missing"):
        rewrite_export(tmp_path)


def test_rewrite_of_a_corrupt_model_is_one_error_line_and_changes_nothing(tmp_path):
    folder = tmp_path / "model"
    _resize_graph_export(folder)
    (folder / FILES["fp32"]).write_bytes(b"not a model")
    argv = [sys.executable, "-m", "gigan_local.rewrite_cli", str(folder)]
    before = snapshot(tmp_path)
    proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=TIMEOUT_S)
    outcome = Outcome(tuple(argv), proc.returncode, proc.stdout, proc.stderr, before, snapshot(tmp_path))
    check_user_error(outcome, f"{folder / FILES['fp32']} is not a loadable ONNX model")


def test_rewrite_of_a_transposed_export_says_there_is_nothing_to_rewrite(tmp_path):
    folder = tmp_path / "model"
    _resize_graph_export(folder)
    cfg = NetworkConfig(name="unet", in_channels=10, out_channels=3, width=8, n_down=5, upsample="transposed")
    (folder / FILES["fp32"]).write_bytes(_onnx(define_G(cfg), (1, 10, 32, 32)).SerializeToString())
    with pytest.raises(UserError, match="no nearest-2x resize"):
        rewrite_export(folder)


def test_the_shipped_model_is_the_rewritten_graph(tmp_path):
    """The shipped files are rewritten, and the fp16 file is the fp32 graph with half-precision weights."""
    doc = json.loads((DEFAULT_MODEL.parent / MODEL_JSON).read_text())
    assert doc["graph"] == GRAPH_NAME
    rewritten = sum(doc["resolution"] // 2 ** (i + 1) >= MIN_SIDE for i in range(doc["n_down"]))
    assert doc["graph_rewrite"]["layers"] == rewritten
    for name in (FILES["fp32"], FILES["fp16"]):
        ops = _ops(onnx.load(str(DEFAULT_MODEL.parent / name)))
        assert ops["DepthToSpace"] == rewritten and ops["Resize"] == doc["n_down"] - rewritten
    shutil.copytree(DEFAULT_MODEL.parent, tmp_path / "copy")
    with pytest.raises(UserError, match="already rewritten"):
        rewrite_export(tmp_path / "copy")
