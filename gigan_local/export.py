"""Export a trained generator to ONNX for the onnxruntime client, with a ``model.json`` beside it.

Output folder::

    model_fp32.onnx   eval-mode generator, input ``input`` (Bx C x R x R), output ``output`` (Bx3xRxR);
                      a resize U-Net's up-sampling rewritten as sub-pixel convolutions (gigan_local.subpixel)
    model_fp16.onnx   the same graph with float16 weights, each followed by a Cast back to float32
    model_int8.onnx   (``int8``) static int8 quantization calibrated on training frames
    model.json        what the client needs: input buffers and encoding, resolution, network config

The batch axis is dynamic, the image size fixed (the U-Net needs sides divisible by 2**n_down, and the
client checks frames against it). In the fp16 file only the stored weights are half precision: the
Casts are constant-folded when onnxruntime loads the model, so it computes in fp32 at fp32 speed from a
file half the size. (Measured with onnxruntime 1.31 on the 2-core CPU at 256 px: a graph converted to
compute in fp16 ran no faster and matched fp32 no better, so the simpler Cast form is kept.)

The int8 file is onnxruntime's static quantization in operator form (QLinearConv: int8 per-channel
weights, uint8 activations with MinMax ranges from training frames). For a transposed-conv U-Net it
quantizes the encoder convolutions only: this form has no quantized ConvTranspose, so the decoder, most of
the work, stays fp32 (a resize U-Net's sub-pixel phase convolutions are quantized too). Measured by
`bench quality` on the 2-core CPU at 256² it was no faster than fp32 beyond the
run-to-run spread (median ratios 0.94-1.25 over four models), with SSIM within 0.0015 of fp32, so it
is an opt-in knob, not the shipped precision. (The QDQ form, which
would cover the decoder too, ran slower than fp32 on this CPU.)
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import TensorProto, helper, numpy_helper

from gicore.error_policy import UserError
from gicore.fileio import TMP_MARKER, atomic_write_bytes, exclusive_run
from gigan_local.config import read_run_config
from gigan_local.inference import FORMAT, MODEL_JSON, read_model_json, trained_resolution
from gigan_local.networks import define_G
from gigan_local.subpixel import GRAPH_NAME, subpixel_upsampling
from gigan_local.train import CHECKPOINT, load_checkpoint

FILES = {"fp32": "model_fp32.onnx", "fp16": "model_fp16.onnx", "int8": "model_int8.onnx"}
INPUT_NAME, OUTPUT_NAME = "input", "output"
TONEMAP_NOTE = (
    "Inputs and output are network values in [-1, 1] (gigan_local.preprocess): radiance is "
    "to_signed(tonemap(x)) with gicore.tonemap (Reinhard x/(1+x), then gamma 1/2.2); invert the output with "
    "inverse_tonemap(from_signed(y)). Where input.albedo_floor is set, the DI input and the output are shading: "
    "radiance divided per channel by max(albedo, albedo_floor), or by 1 where the albedo is 0 in every channel "
    "(no surface); multiply the decoded output by the same (gigan_local.preprocess.albedo_divisor). "
    "GIModel.predict does all of it."
)


@dataclass
class ExportResult:
    """Files written and how closely onnxruntime reproduces torch on a random input."""

    files: dict[str, Path]
    sizes: dict[str, int]
    #: Max |onnxruntime - torch| per variant, on one random input in [-1, 1] (fp32 and fp16: parity).
    max_abs_diff: dict[str, float]
    #: Mean |int8 - fp32| output difference on the run's validation frames (int8 only).
    int8_mean_abs_diff: float | None = None


def load_generator(run_dir: Path) -> tuple[torch.nn.Module, dict[str, Any]]:
    """The eval-mode generator of a training run folder and a summary of its configs."""
    run_dir = Path(run_dir)
    cfg, nets = read_run_config(run_dir)
    ckpt = load_checkpoint(run_dir / CHECKPOINT)
    generator = define_G(nets["G"])
    try:
        generator.load_state_dict(ckpt["model"]["nets"]["G"])
        step = int(ckpt["state"]["step"])
    except (KeyError, TypeError, RuntimeError) as e:  # not a gigan-train checkpoint, or not of this config
        raise UserError(
            f"{run_dir / CHECKPOINT} does not hold the generator described by {run_dir}/config.json "
            f"({type(e).__name__})",
            "export a run folder made by one `gigan-train` run",
        ) from None
    generator.eval()
    info = {"train": cfg, "network": nets["G"], "step": step}
    return generator, info


def fp16_weights(model: onnx.ModelProto) -> onnx.ModelProto:
    """Copy of ``model`` whose float32 initializers are stored as float16 + a Cast node to float32.

    Inputs, outputs and every computation stay float32. Raises ValueError if a weight overflows fp16.
    """
    out = onnx.ModelProto()
    out.CopyFrom(model)
    graph = out.graph
    casts, kept = [], []
    for init in graph.initializer:
        if init.data_type != TensorProto.FLOAT:
            kept.append(init)
            continue
        w = numpy_helper.to_array(init)
        if np.abs(w).max(initial=0.0) > np.finfo(np.float16).max:
            raise ValueError(
                f"weight {init.name} exceeds the float16 range (max |w| = {np.abs(w).max():.3g}); export fp32 only"
            )
        half = numpy_helper.from_array(w.astype(np.float16), name=f"{init.name}__fp16")
        kept.append(half)
        casts.append(
            helper.make_node("Cast", [half.name], [init.name], to=TensorProto.FLOAT, name=f"{init.name}__cast")
        )
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = casts + list(graph.node)  # Casts first keeps the graph topologically sorted
    del graph.node[:]
    graph.node.extend(nodes)
    onnx.checker.check_model(out)
    return out


def calibration_inputs(run_dir: Path, split: str, n: int) -> list[np.ndarray]:
    """Up to ``n`` evenly spaced encoded frames (1xCxRxR) of a run's ``split`` data, for int8 calibration."""
    from gigan_local.data import FrameDataset

    cfg, _ = read_run_config(run_dir)
    try:
        dataset = FrameDataset([Path(d) for d in cfg.datasets], split, cfg.input_spec())
    except UserError as e:
        raise UserError(
            f"int8 export calibrates on the run's {split} frames, which are not readable ({e.what})",
            f"render the datasets of {run_dir}/config.json or export without --int8",
        ) from e
    indices = np.unique(np.linspace(0, len(dataset) - 1, min(n, len(dataset))).round().astype(int))
    return [dataset[int(i)][0].numpy()[None] for i in indices]


def int8_static(fp32_path: Path, out_path: Path, calibration: list[np.ndarray]) -> None:
    """Write a statically quantized copy of ``fp32_path`` (see the module docstring), calibrated on ``calibration``."""
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.inputs = iter(calibration)

        def get_next(self) -> dict[str, np.ndarray] | None:
            x = next(self.inputs, None)
            return None if x is None else {INPUT_NAME: x}

    # The pre-processing and the calibrator write scratch models (sym_shape_infer_temp.onnx, UUID-named external
    # data) into the working folder; run them inside a temporary one so that nothing is left behind.
    source, target = fp32_path.resolve(), out_path.resolve()
    with tempfile.TemporaryDirectory(prefix="gigan-int8-") as scratch, contextlib.chdir(scratch):
        prepared = Path(scratch) / "prepared.onnx"
        # onnx's shape inference suffices (fixed image size); the symbolic one gives up on the sub-pixel graph's
        # computed kernels, which the pre-processing's optimisation then folds into constants to quantize
        quant_pre_process(str(source), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared),
            str(target),
            Reader(),
            quant_format=QuantFormat.QOperator,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
        )


def _ort_outputs(model: Path | bytes, inputs: list[np.ndarray]) -> list[np.ndarray]:
    """The outputs of the model (a file, or its serialized bytes) for each input, from one onnxruntime session."""
    sess = ort.InferenceSession(model if isinstance(model, bytes) else str(model), providers=["CPUExecutionProvider"])
    return [sess.run(None, {INPUT_NAME: x})[0] for x in inputs]


def export_onnx(
    run_dir: Path,
    out_dir: Path,
    opset: int = 17,
    fp16: bool = True,
    int8: bool = False,
    calibration_frames: int = 32,
    seed: int = 0,
) -> ExportResult:
    """Export the generator of ``run_dir`` to ``out_dir`` (fp32, optionally fp16 and int8) with ``model.json``.

    int8 calibrates on ``calibration_frames`` of the run's training frames, so their datasets must exist.
    Each file is written atomically and ``model.json`` last; one export at a time holds ``out_dir``.
    """
    with exclusive_run(Path(out_dir)):
        return _export(Path(run_dir), Path(out_dir), opset, fp16, int8, calibration_frames, seed)


def _export(
    run_dir: Path, out_dir: Path, opset: int, fp16: bool, int8: bool, calibration_frames: int, seed: int
) -> ExportResult:
    if opset < 17:
        raise ValueError(f"opset must be >= 17, got {opset}")
    if int8 and calibration_frames < 1:
        raise ValueError(f"calibration_frames must be >= 1, got {calibration_frames}")
    generator, info = load_generator(run_dir)
    cfg, net = info["train"], info["network"]
    # Read the int8 calibration frames before writing anything: a failed export leaves no files.
    calibration = calibration_inputs(run_dir, "train", calibration_frames) if int8 else []
    val = calibration_inputs(run_dir, "val", 8) if int8 else []
    x = torch.from_numpy(
        np.random.default_rng(seed)
        .uniform(-1, 1, (1, net.in_channels, cfg.resolution, cfg.resolution))
        .astype(np.float32)
    )
    files = {"fp32": out_dir / FILES["fp32"]}
    traced = io.BytesIO()
    with warnings.catch_warnings():
        # The dynamo exporter needs onnxscript, which is not a dependency; the TorchScript one is exact here.
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            generator,
            (x,),
            traced,
            dynamo=False,
            opset_version=opset,
            do_constant_folding=True,
            input_names=[INPUT_NAME],
            output_names=[OUTPUT_NAME],
            dynamic_axes={INPUT_NAME: {0: "batch"}, OUTPUT_NAME: {0: "batch"}},
        )
    model32, rewritten = subpixel_upsampling(onnx.load_from_string(traced.getvalue()))
    atomic_write_bytes(files["fp32"], model32.SerializeToString())
    if fp16:
        files["fp16"] = out_dir / FILES["fp16"]
        atomic_write_bytes(files["fp16"], fp16_weights(model32).SerializeToString())
    with torch.no_grad():
        ref = generator(x).numpy()
    diffs = {k: float(np.abs(_ort_outputs(p, [x.numpy()])[0] - ref).max()) for k, p in files.items()}
    int8_diff = None
    if int8:
        files["int8"] = out_dir / FILES["int8"]
        tmp = files["int8"].with_name(f"{files['int8'].name}{TMP_MARKER}{os.getpid()}")
        try:
            int8_static(files["fp32"], tmp, calibration)
            os.replace(tmp, files["int8"])
        finally:
            tmp.unlink(missing_ok=True)
        pairs = zip(_ort_outputs(files["int8"], val), _ort_outputs(files["fp32"], val))
        int8_diff = float(np.mean([np.abs(q - f).mean() for q, f in pairs]))
    doc = {
        "format": FORMAT,
        "model": cfg.model,
        "run_id": cfg.run_id,
        "step": info["step"],
        "input": cfg.input_spec().to_dict(),
        "in_channels": net.in_channels,
        "resolution": cfg.resolution,
        "ngf": net.width,
        "n_down": net.n_down,
        "network": net.to_dict(),
        "opset": opset,
        **({"graph": GRAPH_NAME} if rewritten else {}),
        "io": {"input": INPUT_NAME, "output": OUTPUT_NAME, "layout": "NCHW", "range": [-1, 1]},
        "files": {k: p.name for k, p in files.items()},
        "tonemap": TONEMAP_NOTE,
        "max_abs_diff_vs_torch": diffs,
    }
    if int8:
        doc["int8"] = {"calibration_frames": len(calibration), "mean_abs_diff_vs_fp32_on_val": int8_diff}
    atomic_write_bytes(out_dir / MODEL_JSON, json.dumps(doc, indent=1).encode())
    return ExportResult(files, {k: p.stat().st_size for k, p in files.items()}, diffs, int8_diff)


def rewrite_export(model_dir: Path, seed: int = 0) -> dict[str, float]:
    """Rewrite an export folder of a resize U-Net in place by :func:`subpixel_upsampling`: ``model_fp32.onnx``,
    the fp16 file re-derived from it, and ``model.json``'s ``graph`` entry (written last). Returns max
    |new - old| per file on one random input in [-1, 1] (float rounding: the graphs compute the same function).
    """
    model_dir = Path(model_dir)
    fp32 = model_dir / FILES["fp32"]
    if not fp32.is_file():
        raise UserError(f"{fp32} is missing", "give a folder that gigan-export wrote")
    doc = read_model_json(fp32)
    if doc.get("graph") == GRAPH_NAME:
        raise UserError(
            f"{model_dir} is already rewritten (model.json: graph {GRAPH_NAME!r})", "use the folder as it is"
        )
    with exclusive_run(model_dir):
        try:
            original = onnx.load(str(fp32))
        except Exception as e:  # onnx raises protobuf's own exception types for unreadable files
            raise UserError(
                f"{fp32} is not a loadable ONNX model ({type(e).__name__})", "re-export it with gigan-export"
            ) from None
        new32, n = subpixel_upsampling(original)
        if n == 0:
            raise UserError(
                f"{fp32} has no nearest-2x resize + 3x3 conv to rewrite",
                "only a resize U-Net's export is rewritten (transposed up-sampling has no Resize)",
            )
        files = {"fp32": new32}
        if (model_dir / FILES["fp16"]).is_file():
            files["fp16"] = fp16_weights(new32)
        side = int(doc["resolution"])
        x = np.random.default_rng(seed).uniform(-1, 1, (1, int(doc["in_channels"]), side, side)).astype(np.float32)
        diffs = {}
        for k, model in files.items():
            old, new = _ort_outputs(model_dir / FILES[k], [x])[0], _ort_outputs(model.SerializeToString(), [x])[0]
            diffs[k] = float(np.abs(new - old).max())
        for k, model in files.items():
            atomic_write_bytes(model_dir / FILES[k], model.SerializeToString())
        doc["graph"] = GRAPH_NAME
        doc["graph_rewrite"] = {"layers": n, "max_abs_diff_vs_resize_graph": diffs}
        atomic_write_bytes(model_dir / MODEL_JSON, json.dumps(doc, indent=1).encode())
    return diffs


def resize_export(model_dir: Path, out_dir: Path, resolution: int, seed: int = 0) -> dict[str, float]:
    """The export in ``model_dir`` again in ``out_dir``, for frames of ``resolution``²: the same weights and graph,
    its input and output sides set to ``resolution`` (a U-Net is fully convolutional at any side divisible by
    2**n_down). Its cost is that of the network at the new side; its quality there is not what a model trained
    at that side reaches, so ``model.json`` keeps the side it was trained at as ``trained_resolution``.

    Returns max |onnxruntime - torch| per file on one random input at the new side, torch being the generator
    built from the file's weights: the check that the resized graph computes the network."""
    from gigan_local.config import NetworkConfig
    from gigan_local.preprocess import InputSpec
    from gigan_local.warmstart import load_into

    fp32 = Path(model_dir) / FILES["fp32"]
    if not fp32.is_file():
        raise UserError(f"{fp32} is missing", "give a folder that gigan-export wrote")
    doc = read_model_json(fp32)
    network = NetworkConfig.from_dict(doc["network"])
    try:
        network.check_size(resolution)
    except ValueError as e:
        raise UserError(f"--resolution {resolution}: {e}", f"use a multiple of {2**network.n_down}") from None
    graph32 = onnx.load(str(fp32))
    for value in (*graph32.graph.input, *graph32.graph.output):
        dims = value.type.tensor_type.shape.dim
        dims[2].dim_value = dims[3].dim_value = resolution
    del graph32.graph.value_info[:]  # shapes inferred at the old side
    models = {"fp32": graph32} | ({"fp16": fp16_weights(graph32)} if "fp16" in doc["files"] else {})
    generator = define_G(network)
    load_into(generator, fp32, network, InputSpec.from_dict(doc["input"]), calibration=None)
    x = np.random.default_rng(seed).uniform(-1, 1, (1, network.in_channels, resolution, resolution))
    x = x.astype(np.float32)
    with torch.no_grad():
        ref = generator.eval()(torch.from_numpy(x)).numpy()
    diffs = {k: float(np.abs(_ort_outputs(m.SerializeToString(), [x])[0] - ref).max()) for k, m in models.items()}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with exclusive_run(out_dir):
        for k, model in models.items():
            atomic_write_bytes(out_dir / FILES[k], model.SerializeToString())
        resized = doc | {
            "resolution": resolution,
            "trained_resolution": trained_resolution(doc),
            "files": {k: FILES[k] for k in models},
            "max_abs_diff_vs_torch": diffs,
        }
        resized.pop("int8", None)
        atomic_write_bytes(out_dir / MODEL_JSON, json.dumps(resized, indent=1).encode())
    return diffs
