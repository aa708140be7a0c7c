"""Resize up-sampling as sub-pixel convolutions: the same generator, exactly, in a faster ONNX graph.

A nearest 2x resize followed by a 3x3 convolution (padding 1) computes each output pixel ``(2i + dy, 2j + dx)``
from a 2x2 window of the input, so the layer is four 2x2 convolutions on the low-resolution input, one per
phase, interleaved by ``DepthToSpace`` (Shi et al. 2016): 4/9 of the multiply-adds and no resized image;
outputs differ from the resize graph by float rounding only. The outermost layer (3 output channels) is one
3x3 convolution with 12 outputs instead, since onnxruntime rounds output channels up to its block; layers on
inputs under :data:`MIN_SIDE` pixels stay as they are. The file keeps each 3x3 weight; the phase kernels are
computed from it in the graph and folded by onnxruntime at load. :func:`subpixel_upsampling` rewrites a model
``torch.onnx.export`` wrote; ``gigan-export`` applies it, and ``python -m gigan_local.rewrite_cli MODEL_DIR``
rewrites an export folder in place. docs/architecture.md, Exported model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import onnx
from onnx import helper, numpy_helper

#: ``TAPS[p][a, k]``: 1 where kernel row ``k`` of the 3x3 conv on the resized image falls on input row
#: ``i - 1 + a`` for output row ``2i + p`` (and the same for columns).
TAPS = np.array([[[1, 0, 0], [0, 1, 1], [0, 0, 0]], [[0, 0, 0], [1, 1, 0], [0, 0, 1]]], dtype=np.float64)
#: Output channels from which each phase gets its own 2x2 convolution (one onnxruntime channel block).
SPLIT_MIN_CHANNELS = 16
#: Layers whose input is smaller than this on a side stay resize + conv. They cost little (the U-Net's
#: innermost: 1x1 to 4x4 inputs), and onnxruntime-web 1.30's WebGPU convolution computes a 2x2 kernel padded
#: on one side wrongly on a 2x2 input (max |error| 63 against its wasm back end; one-sided pads from 4x4 up
#: matched to 1e-4), which made the browser's GPU path wrong.
MIN_SIDE = 8
#: Joins a layer's weight (or bias) name and a tag (``ups.0.2.weight#subpixel/phases``, ``...#subpixel/taps01``):
#: the part before it is the name ``torch.onnx.export`` gave, which :func:`exported_convs` gives back.
PHASE_SEP = "#subpixel/"
#: What ``model.json`` records of the rewrite (its ``graph`` entry).
GRAPH_NAME = "subpixel"


@dataclass(frozen=True)
class _Layer:
    """One resize -> conv pair of the graph."""

    resize: onnx.NodeProto
    conv: onnx.NodeProto
    weight: np.ndarray  # (out, in, 3, 3): its shape and dtype shape the phase kernels


def _constant(graph: onnx.GraphProto, name: str) -> np.ndarray | None:
    for init in graph.initializer:
        if init.name == name:
            return numpy_helper.to_array(init)
    for node in graph.node:
        if node.op_type == "Constant" and node.output[0] == name:
            return numpy_helper.to_array(node.attribute[0].t)
    return None


def _is_nearest_2x(graph: onnx.GraphProto, node: onnx.NodeProto) -> bool:
    attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
    scales = _constant(graph, node.input[2]) if len(node.input) > 2 and node.input[2] else None
    return (
        attrs.get("mode") == b"nearest"
        and attrs.get("coordinate_transformation_mode") == b"asymmetric"
        and attrs.get("nearest_mode") == b"floor"
        and scales is not None
        and scales.tolist() == [1.0, 1.0, 2.0, 2.0]
    )


def _is_plain_3x3(conv: onnx.NodeProto) -> bool:
    attrs = {a.name: helper.get_attribute_value(a) for a in conv.attribute}
    return (
        attrs.get("kernel_shape") == [3, 3]
        and attrs.get("pads") == [1, 1, 1, 1]
        and attrs.get("strides", [1, 1]) == [1, 1]
        and attrs.get("dilations", [1, 1]) == [1, 1]
        and attrs.get("group", 1) == 1
        and attrs.get("auto_pad", b"NOTSET") == b"NOTSET"
    )


def _sides(model: onnx.ModelProto) -> dict[str, tuple[int, int]]:
    """(height, width) of every 4-D tensor whose spatial size shape inference can tell."""
    inferred = onnx.shape_inference.infer_shapes(model).graph
    sides = {}
    for value in [*inferred.input, *inferred.value_info]:
        dims = value.type.tensor_type.shape.dim
        if len(dims) == 4 and dims[2].dim_value > 0 and dims[3].dim_value > 0:
            sides[value.name] = (dims[2].dim_value, dims[3].dim_value)
    return sides


def _layers(model: onnx.ModelProto) -> list[_Layer]:
    """Every nearest-2x Resize of an input at least :data:`MIN_SIDE` on each side whose only consumer is a
    plain 3x3 Conv with constant weights."""
    graph, sides = model.graph, _sides(model)
    consumers: dict[str, list[onnx.NodeProto]] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    outputs = {o.name for o in graph.output}
    layers = []
    for node in graph.node:
        if node.op_type != "Resize" or not _is_nearest_2x(graph, node) or node.output[0] in outputs:
            continue
        if min(sides.get(node.input[0], (0, 0))) < MIN_SIDE:
            continue
        users = consumers.get(node.output[0], [])
        if len(users) != 1 or users[0].op_type != "Conv" or not _is_plain_3x3(users[0]):
            continue
        conv = users[0]
        weight = _constant(graph, conv.input[1])
        if weight is None:
            continue
        layers.append(_Layer(node, conv, weight))
    return layers


def phase_taps(dy: int, dx: int, window: int) -> np.ndarray:
    """``(9, window**2)``: the flattened 3x3 kernel on the resized input times this matrix is the kernel on
    the input of phase ``(dy, dx)``: its 2x2 window (``window`` 2) or the 3x3 it sits in, zeros elsewhere
    (``window`` 3)."""
    taps = np.kron(TAPS[dy], TAPS[dx]).reshape(3, 3, 9)  # (input row, input column, kernel tap)
    if window == 2:
        taps = taps[dy : dy + 2, dx : dx + 2]
    return taps.reshape(window * window, 9).T


def _phase_nodes(layer: _Layer, graph: onnx.GraphProto) -> list[onnx.NodeProto]:
    """The nodes (and, added to ``graph``, their constants) that replace ``layer``'s resize and conv."""
    source, target = layer.resize.input[0], layer.conv.output[0]
    weight, bias = layer.conv.input[1], layer.conv.input[2] if len(layer.conv.input) > 2 else ""
    out_channels, in_channels = layer.weight.shape[:2]
    dtype = layer.weight.dtype

    def name(tag: str) -> str:
        return f"{weight}{PHASE_SEP}{tag}"

    def constant(tag: str, value: np.ndarray) -> str:
        graph.initializer.append(numpy_helper.from_array(value, name(tag)))
        return name(tag)

    window = 3 if out_channels < SPLIT_MIN_CHANNELS else 2
    flat = name("flat")
    nodes = [helper.make_node("Reshape", [weight, constant("flat_shape", np.array([-1, 9]))], [flat])]
    shape = constant("kernel_shape", np.array([out_channels, in_channels, window, window]))
    kernels = []
    for dy in (0, 1):
        for dx in (0, 1):
            taps = constant(f"taps{dy}{dx}", phase_taps(dy, dx, window).astype(dtype))
            kernels.append(name(f"phase{dy}{dx}"))
            nodes += [
                helper.make_node("MatMul", [flat, taps], [f"{kernels[-1]}{PHASE_SEP}flat"]),
                helper.make_node("Reshape", [f"{kernels[-1]}{PHASE_SEP}flat", shape], [kernels[-1]]),
            ]
    phases = f"{target}{PHASE_SEP}phases"
    if window == 3:  # one conv: the four phases' kernels stacked as output channels
        nodes.append(helper.make_node("Concat", kernels, [name("phases")], axis=0))
        biases = [helper.make_node("Concat", [bias] * 4, [f"{bias}{PHASE_SEP}phases"], axis=0)] if bias else []
        conv_bias = [f"{bias}{PHASE_SEP}phases"] if bias else []
        nodes += [*biases, helper.make_node("Conv", [source, name("phases"), *conv_bias], [phases],
                                            kernel_shape=[3, 3], pads=[1, 1, 1, 1])]  # fmt: skip
    else:
        outs = []
        for (dy, dx), kernel in zip(((0, 0), (0, 1), (1, 0), (1, 1)), kernels, strict=True):
            outs.append(f"{target}{PHASE_SEP}phase{dy}{dx}")
            pads = [1 - dy, 1 - dx, dy, dx]  # top, left, bottom, right: the window reaches one row/column out
            inputs = [source, kernel, bias] if bias else [source, kernel]
            nodes.append(helper.make_node("Conv", inputs, [outs[-1]], kernel_shape=[2, 2], pads=pads))
        nodes.append(helper.make_node("Concat", outs, [phases], axis=1))
    # DCR: output channel c at (2i + dy, 2j + dx) is input channel (2 dy + dx) * C + c, the phases' order.
    nodes.append(helper.make_node("DepthToSpace", [phases], [target], blocksize=2, mode="DCR"))
    base = layer.conv.name or target
    for k, node in enumerate(nodes):
        node.name = f"{base}{PHASE_SEP}{k}"
    return nodes


def subpixel_upsampling(model: onnx.ModelProto) -> tuple[onnx.ModelProto, int]:
    """A copy of ``model`` with every nearest-2x resize + 3x3 conv as phase convolutions (module docstring),
    and how many layers were rewritten (0: the copy computes as ``model`` does, e.g. transposed convs)."""
    out = onnx.ModelProto()
    out.CopyFrom(model)
    graph = out.graph
    layers = _layers(out)
    replaced = {id(layer.conv): _phase_nodes(layer, graph) for layer in layers}
    dropped = {id(layer.resize) for layer in layers}
    nodes = []
    for node in graph.node:
        if id(node) in replaced:
            nodes += replaced[id(node)]
        elif id(node) not in dropped:
            nodes.append(node)
    used = {name for node in nodes for name in node.input}
    nodes = [n for n in nodes if n.op_type != "Constant" or n.output[0] in used]  # the resizes' scales
    kept = [init for init in graph.initializer if init.name in used]
    del graph.node[:]
    graph.node.extend(nodes)
    del graph.initializer[:]
    graph.initializer.extend(kept)
    onnx.checker.check_model(out)
    return out, len(layers)


def exported_convs(graph: onnx.GraphProto, weights: dict[str, np.ndarray]) -> list[tuple[str, str]]:
    """The exported layers' convolutions in graph order as (weight, bias or "") initializer names: a rewritten
    layer's phase convolutions count as the one 3x3 convolution whose weight (and bias) they are computed
    from. The rewrite's own constants (names holding :data:`PHASE_SEP`) are removed from ``weights`` (name ->
    array), so that a reader of the weights (a warm start) sees what ``torch.onnx.export`` wrote."""
    listed: dict[str, str] = {}  # weight -> bias, in graph order; a layer's phase convs share its weight
    for node in (n for n in graph.node if n.op_type == "Conv"):
        bias = node.input[2] if len(node.input) > 2 else ""
        listed.setdefault(node.input[1].partition(PHASE_SEP)[0], bias.partition(PHASE_SEP)[0])
    for name in [name for name in weights if PHASE_SEP in name]:
        del weights[name]
    return list(listed.items())
