"""Warm starts (`gigan-train --init-generator`): the shipped model's weights read back into torch."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch

from gicore.error_policy import UserError
from gigan_local.config import NetworkConfig
from gigan_local.inference import DEFAULT_MODEL
from gigan_local.networks import define_G
from gigan_local.preprocess import InputSpec
from gigan_local.warmstart import generator_weights, init_depth_scale, load_into

SHIPPED = DEFAULT_MODEL.parent


def _shipped() -> tuple[NetworkConfig, InputSpec]:
    doc = json.loads((SHIPPED / "model.json").read_text())
    return NetworkConfig.from_dict(doc["network"]), InputSpec.from_dict(doc["input"])


def _smallest_side() -> int:
    """The smallest frame side the shipped U-Net runs on (a 1x1 bottleneck)."""
    return 2 ** _shipped()[0].n_down


def _loaded(name: str, calibration: torch.Tensor | None = None) -> torch.nn.Module:
    net, spec = _shipped()
    generator = define_G(net)
    # conv and batch norm folded on export: downs 1 .. n-2, and with resize up-sampling every up layer but the outermost
    folded = (net.n_down - 2) + (net.n_down - 1 if net.upsample == "resize" else 0)
    assert load_into(generator, SHIPPED / name, net, spec, calibration) == folded
    return generator.eval()


def _input(seed: int, side: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (1, _shipped()[0].in_channels, side, side)).astype(np.float32)


@pytest.mark.parametrize("calibrated", [False, True])
def test_warm_started_generator_computes_the_exported_model(calibrated: bool) -> None:
    side = int(json.loads((SHIPPED / "model.json").read_text())["resolution"])
    x = _input(1, side)
    generator = _loaded("model_fp32.onnx", torch.from_numpy(_input(2, side)) if calibrated else None)
    with torch.no_grad():
        y_torch = generator(torch.from_numpy(x)).numpy()
    y_onnx = ort.InferenceSession(str(SHIPPED / "model_fp32.onnx"), providers=["CPUExecutionProvider"]).run(
        None, {"input": x}
    )[0]
    assert np.abs(y_torch - y_onnx).max() < 1e-4
    assert np.abs(y_onnx).max() > 0.1  # a real prediction, not an all-zero output


def test_fp16_file_gives_the_fp32_weights_up_to_half_precision() -> None:
    x = torch.from_numpy(_input(3, _smallest_side()))
    with torch.no_grad():
        y16, y32 = _loaded("model_fp16.onnx")(x), _loaded("model_fp32.onnx")(x)
    assert 0 < float((y16 - y32).abs().max()) < 2e-2


def test_calibration_makes_training_mode_batch_norm_start_where_the_model_is() -> None:
    """In training mode batch norm normalises with the batch's own statistics: after calibrating on a
    batch, that batch gives the eval-mode output again (the folded layers add exactly b')."""
    x = torch.from_numpy(np.concatenate([_input(s, _smallest_side()) for s in range(4)]))
    generator = _loaded("model_fp32.onnx", x)
    with torch.no_grad():
        y_eval = generator(x)
        downs = generator.downs.train()  # batch norm in training mode, dropout (in the ups) still off
        y_train = generator(x)
        downs.eval()
        uncalibrated = _loaded("model_fp32.onnx").downs.train()
    assert float((y_train - y_eval).abs().max()) < 0.05
    with torch.no_grad():
        y_uncal = generator.__class__.forward(_with_downs(generator, uncalibrated), x)
    assert float((y_uncal - y_eval).abs().max()) > 10 * float((y_train - y_eval).abs().max())


def _with_downs(generator: torch.nn.Module, downs: torch.nn.Module) -> torch.nn.Module:
    generator.downs = downs
    return generator


def test_depth_scale_comes_from_the_model() -> None:
    assert init_depth_scale(SHIPPED / "model_fp16.onnx") == _shipped()[1].depth_scale


def test_a_different_architecture_is_refused_naming_the_field() -> None:
    net, spec = _shipped()
    with pytest.raises(UserError, match="width"):
        generator_weights(SHIPPED / "model_fp16.onnx", replace(net, width=net.width * 2), spec)
    with pytest.raises(UserError, match="encodes inputs"):
        generator_weights(SHIPPED / "model_fp16.onnx", net, InputSpec(("di", "albedo"), spec.depth_scale))
    with pytest.raises(UserError, match="--demodulate"):  # the shipped model's output is radiance
        generator_weights(SHIPPED / "model_fp16.onnx", net, replace(spec, albedo_floor=0.05))


def test_a_missing_model_json_is_a_user_error(tmp_path: Path) -> None:
    shutil.copy(SHIPPED / "model_fp16.onnx", tmp_path / "model_fp16.onnx")
    net, spec = _shipped()
    with pytest.raises(UserError, match="model.json"):
        generator_weights(tmp_path / "model_fp16.onnx", net, spec)
    with pytest.raises(UserError, match="is not a file"):
        generator_weights(tmp_path / "absent.onnx", net, spec)


def test_gigan_train_fine_tunes_the_exported_model(tmp_path: Path) -> None:
    """`gigan-train --init-generator`: step 0 of the run is the exported model (its validation equals the
    model's own on those frames), the depth scale is the model's, and a wrong architecture is refused."""
    from typer.testing import CliRunner

    from gigan_local.train import CHECKPOINT, load_checkpoint
    from gigan_local.train_cli import app
    from tests.helpers.training import make_dataset

    net = _shipped()[0]
    data = make_dataset(tmp_path / "ds", res=_smallest_side(), n_train=2, n_val=1)
    out = tmp_path / "run"
    args = [
        str(data),
        "--out",
        str(out),
        "--ngf",
        "16",
        "--n-down",
        str(net.n_down),
        "--upsample",
        net.upsample,
        "--batch-size",
        "2",
        "--no-progress",
    ]
    res = CliRunner().invoke(app, [*args, "--init-generator", str(SHIPPED / "model_fp16.onnx"), "--max-steps", "0"])
    assert res.exit_code == 0, res.output
    config = json.loads((out / "config.json").read_text())["train"]
    assert (
        config["init_generator"] == str(SHIPPED / "model_fp16.onnx")
        and config["depth_scale"] == _shipped()[1].depth_scale
    )
    g = load_checkpoint(out / CHECKPOINT)["model"]["nets"]["G"]
    expected = _loaded("model_fp16.onnx").state_dict()
    outer_bias = next(k for k in expected if k.startswith("ups.0.") and k.endswith(".bias"))  # the outermost up conv's
    assert torch.equal(g[outer_bias], expected[outer_bias]) and torch.equal(
        g["downs.0.0.weight"], expected["downs.0.0.weight"]
    )
    narrower = [
        str(data),
        "--out",
        str(tmp_path / "r2"),
        "--ngf",
        "8",
        "--n-down",
        str(net.n_down),
        "--upsample",
        net.upsample,
        "--no-progress",
    ]
    res = CliRunner().invoke(app, [*narrower, "--init-generator", str(SHIPPED / "model_fp16.onnx"), "--max-steps", "0"])
    assert (
        isinstance(res.exception, UserError)
        and "different generator" in str(res.exception)
        and "width" in str(res.exception)
    )
