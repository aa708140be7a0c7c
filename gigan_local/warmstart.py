"""Warm starts: a generator's weights read back from a model that ``gigan-export`` wrote.

``gigan-train --init-generator MODEL.onnx`` fine-tunes an exported generator instead of starting from
random weights (e.g. to adapt a model trained on crops to whole frames): the ONNX initializers carry
the torch state-dict names and values (batch-norm statistics included; fp16 files are widened back to
fp32), and the ``model.json`` beside the file says which architecture and input encoding they belong to.
A critic, when the model has one, starts fresh: exported files hold only the generator.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gicore.error_policy import UserError
from gigan_local.config import NetworkConfig
from gigan_local.inference import MODEL_JSON, read_model_json
from gigan_local.preprocess import InputSpec

#: State-dict entries that exports do not carry and that a warm start may leave at their initial value.
NOT_EXPORTED = ("num_batches_tracked",)


def _model_json(path: Path) -> dict[str, Any]:
    """The exported model's ``model.json`` (:func:`gigan_local.inference.read_model_json`), with its
    generator architecture checked too."""
    path = Path(path)
    if not path.is_file():
        raise UserError(
            f"--init-generator {path} is not a file",
            "give a model_fp32.onnx or model_fp16.onnx written by gigan-export",
        )
    doc = read_model_json(path)
    try:
        NetworkConfig.from_dict(doc["network"])
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise UserError(
            f"{path.parent / MODEL_JSON} has no valid generator architecture ({e})",
            "re-export the model with gigan-export",
        ) from None
    return doc


def init_depth_scale(path: Path) -> float:
    """The depth scale the exported model's inputs were encoded with (a warm start must keep it)."""
    return float(InputSpec.from_dict(_model_json(path)["input"]).depth_scale)


def generator_weights(
    path: Path, network: NetworkConfig, spec: InputSpec
) -> tuple[dict[str, np.ndarray], list[tuple[str, str]]]:
    """The exported generator's weights, checked against the run's generator ``network`` and input
    ``spec`` (a mismatch is a UserError saying which field differs): (initializer name -> float32 array,
    and the graph's ``Conv`` nodes in graph order as (weight, bias or "") initializer names, a sub-pixel
    layer's phase convolutions counted as the 3x3 one they come from:
    :func:`gigan_local.subpixel.exported_convs`)."""
    import onnx
    from onnx import numpy_helper

    from gigan_local.subpixel import exported_convs

    doc = _model_json(path)
    saved_net, saved_spec = NetworkConfig.from_dict(doc["network"]), InputSpec.from_dict(doc["input"])
    if saved_net != network:
        diff = {k: (v, getattr(network, k)) for k, v in vars(saved_net).items() if getattr(network, k) != v}
        raise UserError(
            f"--init-generator {path} is a different generator than this run builds (model vs run: {diff})",
            "give the run the model's architecture (--model, --ngf, --n-down, --buffers) or start from random weights",
        )
    same_floor = saved_spec.albedo_floor == spec.albedo_floor
    if saved_spec.buffers != spec.buffers or not np.isclose(saved_spec.depth_scale, spec.depth_scale) or not same_floor:
        raise UserError(
            f"--init-generator {path} encodes inputs {saved_spec.to_dict()}, this run {spec.to_dict()}",
            "train on the model's buffers and demodulation (--demodulate), and leave the depth scale to the model",
        )
    try:
        graph = onnx.load(str(path)).graph
    except Exception as e:  # onnx raises protobuf's own exception types for unreadable files
        raise UserError(
            f"{path} is not a loadable ONNX model ({type(e).__name__})", "re-export it with gigan-export"
        ) from None
    # an fp16 file stores each weight in half precision followed by a Cast: a weight is named by what it feeds
    cast_of = {n.input[0]: n.output[0] for n in graph.node if n.op_type == "Cast"}
    weights = {cast_of.get(t.name, t.name): numpy_helper.to_array(t).astype(np.float32) for t in graph.initializer}
    return weights, exported_convs(graph, weights)


def load_into(generator: Any, path: Path, network: NetworkConfig, spec: InputSpec, calibration: Any) -> int:
    """Load the exported generator at ``path`` into the torch ``generator`` (a U-Net of ``network``).

    Every parameter and buffer but :data:`NOT_EXPORTED` must be in the file with its shape, except for
    a layer (a down layer or a resize up layer) whose convolution the exporter folded together with its
    batch norm (torch.onnx does that in eval mode): its folded weight W' and bias b' are loaded as the
    convolution's weight and a batch norm that adds b' -- running mean m and variance v, scale
    sqrt(v + eps), shift b' + m, exact in eval mode for any m, v. ``calibration`` (an input batch,
    N x C x H x W) sets m and v to the batch statistics of W' x, so that training-mode batch norm starts out
    computing what the model computed.
    Returns the number of folded layers restored that way. Any other mismatch is a UserError.
    """
    import torch

    weights, convs = generator_weights(path, network, spec)
    state = generator.state_dict()
    layers = _conv_layers(generator)
    folded: list[tuple[torch.nn.Conv2d, torch.nn.BatchNorm2d, np.ndarray]] = []
    for k, (w_name, b_name) in enumerate(convs):
        if w_name in state or k >= len(layers):
            continue
        prefix, layer = layers[k]
        modules = list(layer)
        j = next((i for i, m in enumerate(modules) if isinstance(m, torch.nn.Conv2d)), None)
        if j is None or j + 1 >= len(modules) or not isinstance(modules[j + 1], torch.nn.BatchNorm2d) or not b_name:
            continue
        weights[f"{prefix}.{j}.weight"] = weights.pop(w_name)
        b = weights.pop(b_name)
        bn = modules[j + 1]
        for field, value in (("running_mean", np.zeros_like(b)), ("running_var", np.ones_like(b)), ("bias", b)):
            weights[f"{prefix}.{j + 1}.{field}"] = value
        weights[f"{prefix}.{j + 1}.weight"] = np.full_like(b, np.sqrt(1.0 + bn.eps))
        folded.append((modules[j], bn, b))
    needed = {k for k in state if not k.endswith(NOT_EXPORTED)}
    missing, extra = sorted(needed - set(weights)), sorted(set(weights) - set(state))
    if missing or extra:
        raise UserError(
            f"{path} does not hold this generator's weights (missing {missing[:3]}, unexpected {extra[:3]})",
            "re-export it with gigan-export",
        )
    for name in needed:
        if tuple(weights[name].shape) != tuple(state[name].shape):
            what = f"{path}: weight {name} is {weights[name].shape}, the generator's {tuple(state[name].shape)}"
            raise UserError(what, "re-export it with gigan-export")
        state[name] = torch.from_numpy(weights[name]).to(state[name].dtype)
    generator.load_state_dict(state)
    if folded and calibration is not None:
        _calibrate(generator, folded, calibration)
    return len(folded)


def _conv_layers(generator: Any) -> list[tuple[str, Any]]:
    """The U-Net's layers that hold a ``Conv2d``, as (state-dict prefix, layer), in the order the forward
    pass runs them, which is the order of the exported graph's ``Conv`` nodes: the down layers, then the
    up layers from the innermost out (only resize up layers: a transposed conv is a ``ConvTranspose``)."""
    import torch

    downs = [(f"downs.{i}", m) for i, m in enumerate(getattr(generator, "downs", []))]
    ups = [(f"ups.{i}", m) for i, m in reversed(list(enumerate(getattr(generator, "ups", []))))]
    return [(name, m) for name, m in downs + ups if any(isinstance(x, torch.nn.Conv2d) for x in m)]


def _calibrate(generator: Any, folded: list, inputs: Any) -> None:
    """Set each folded layer's running statistics to those of its convolution's output on ``inputs``,
    keeping the eval-mode function unchanged (see :func:`load_into`)."""
    import torch

    stats: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    def record(i: int):
        def hook(module: Any, args: Any, out: torch.Tensor) -> None:
            stats[i] = out.mean(dim=(0, 2, 3)), out.var(dim=(0, 2, 3), unbiased=False)

        return hook

    hooks = [conv.register_forward_hook(record(i)) for i, (conv, _, _) in enumerate(folded)]
    was_training = generator.training
    generator.eval()
    try:
        with torch.no_grad():
            generator(inputs)
    finally:
        for h in hooks:
            h.remove()
        generator.train(was_training)
    with torch.no_grad():
        for i, (_, bn, b) in enumerate(folded):
            mean, var = stats[i]
            bn.running_mean.copy_(mean)
            bn.running_var.copy_(var)
            bn.weight.copy_(torch.sqrt(var + bn.eps))
            bn.bias.copy_(torch.from_numpy(b) + mean)
