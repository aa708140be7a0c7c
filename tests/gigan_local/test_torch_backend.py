"""GIGAN's generator on torch (`--inference torch`): the ONNX file's weights in the torch network, the same
predictions as onnxruntime's on the same file, and the choice between the two backends."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gicore.cuda_probe import cuda_device_count
from gicore.error_policy import UserError
from gigan_local.backend_choice import open_model, resolve_inference
from gigan_local.inference import DEFAULT_MODEL, GIModel
from gigan_local.preprocess import CHANNELS, frame_divisor, frame_to_input, output_to_radiance
from gigan_local.torch_backend import TorchGIModel, decode_output, encode_frame
from tests.helpers.guards import HANG_GUARD_S

#: Largest difference between the two backends' predictions (linear radiance) on the shipped model.
PREDICT_TOLERANCE = 1e-3


@pytest.fixture(scope="module")
def frame(make_spec) -> dict[str, np.ndarray]:
    """The sphere-and-box scene's DI + G-buffers at the shipped model's resolution, as the model source
    renders them at the GI camera."""
    from gicore.paths import camera_path, light_position
    from gicore.render import Renderer

    resolution = int(json.loads((DEFAULT_MODEL.parent / "model.json").read_text())["resolution"])
    renderer = Renderer(make_spec(with_box=True), resolution)
    camera = camera_path(renderer.spec, 40, fov=90.0, resolution=resolution)[3]
    return renderer.render_di_gbuffers(camera, light_position(renderer.spec, 3), centre=True)


@pytest.mark.parametrize("name", ["model_fp16.onnx", "model_fp32.onnx"])
def test_torch_on_the_cpu_predicts_what_onnxruntime_predicts(frame, name):
    path = DEFAULT_MODEL.parent / name
    reference = GIModel(path, threads=1, warmup=0).predict(frame)
    model = TorchGIModel(path, threads=1, warmup=0)
    if model.device.type == "cuda":
        pytest.skip("torch runs on CUDA here (float16): the CPU comparison is for machines without a GPU")
    predicted = model.predict(frame)
    assert model.backend.startswith("torch cpu float32")
    assert predicted.shape == reference.shape == (*frame["di"].shape[:2], 3) and predicted.flags.c_contiguous
    assert np.abs(predicted - reference).max() <= PREDICT_TOLERANCE
    assert reference.max() > 0.05  # real GI, not an all-dark map that any two backends agree on


def test_the_device_encoding_is_the_host_encoding():
    """encode_frame and decode_output (on the torch backend's device) against preprocess's numpy functions, on
    buffers with negative, large and zero values."""
    import torch

    model_json = json.loads((DEFAULT_MODEL.parent / "model.json").read_text())
    spec = GIModel(DEFAULT_MODEL, threads=1, warmup=0).spec
    rng = np.random.default_rng(7)
    frame = {b: (rng.standard_normal((24, 20, CHANNELS[b])) * 50.0).astype(np.float32) for b in spec.buffers}
    frame[spec.buffers[0]][0, 0] = 0.0
    encoded = encode_frame({b: torch.from_numpy(a) for b, a in frame.items()}, spec).numpy()
    assert encoded.shape == (model_json["in_channels"], 24, 20)
    np.testing.assert_allclose(encoded, frame_to_input(frame, spec), rtol=1e-6, atol=1e-6)
    y = rng.uniform(-1.2, 1.2, (3, 24, 20)).astype(np.float32)
    np.testing.assert_allclose(decode_output(torch.from_numpy(y), spec).numpy(), output_to_radiance(y, spec), rtol=1e-5)
    # albedo-demodulated: the DI divided and the output multiplied by the same albedo divisor on both
    demodulated = replace(spec, albedo_floor=0.05)
    frame["albedo"] = np.clip(frame["albedo"], 0.0, 1.0)
    frame["albedo"][:3] = 0.0  # no surface
    raw = {b: torch.from_numpy(a) for b, a in frame.items()}
    encoded = encode_frame(raw, demodulated).numpy()
    np.testing.assert_allclose(encoded, frame_to_input(frame, demodulated), rtol=1e-5, atol=1e-5)
    decoded = decode_output(torch.from_numpy(y), demodulated, raw["albedo"]).numpy()
    np.testing.assert_allclose(
        decoded, output_to_radiance(y, demodulated, frame_divisor(frame, demodulated)), rtol=1e-5
    )


def test_a_nan_in_a_buffer_is_an_error_naming_it(frame):
    model = TorchGIModel(DEFAULT_MODEL, threads=1, warmup=0)
    broken = frame | {"depth": frame["depth"].copy()}
    broken["depth"][5, 5] = np.nan
    with pytest.raises(ValueError, match=r"buffer\(s\) \['depth'\] contain NaN or Inf"):
        model.predict(broken)
    with pytest.raises(ValueError, match="must be an HxWx3 array"):
        model.predict(frame | {"albedo": frame["albedo"][..., :1]})


@pytest.mark.skipif(not cuda_device_count(), reason="needs a CUDA GPU; CI has none")
def test_the_cuda_graph_predicts_what_the_eager_network_predicts(frame):
    """On CUDA, predict replays the captured graph: the same radiance as the eager kernels on the same frame, and
    the graph's outputs are copied out, so a later frame does not change an earlier prediction."""
    import torch

    model = TorchGIModel(DEFAULT_MODEL, threads=1, warmup=1)
    assert model._captured is not None and model.backend.endswith("CUDA graph")
    replayed = model.predict(frame)
    with torch.inference_mode():
        eager = model._forward({b: torch.from_numpy(np.ascontiguousarray(frame[b])).to("cuda") for b in model.buffers})
    np.testing.assert_allclose(replayed, eager[0].cpu().numpy(), rtol=1e-2, atol=1e-3)
    model.predict({b: np.zeros_like(a) for b, a in frame.items()})
    np.testing.assert_array_equal(replayed, model.predict(frame))


def test_auto_is_torch_on_cuda_and_onnxruntime_without():
    assert resolve_inference("auto", cuda=True) == "torch"
    assert resolve_inference("auto", cuda=False) == "onnxruntime"
    for forced in ("onnxruntime", "torch"):
        assert resolve_inference(forced, cuda=True) == resolve_inference(forced, cuda=False) == forced
    with pytest.raises(UserError, match="--inference 'tensorflow' is not a backend: use one of auto, onnxruntime"):
        resolve_inference("tensorflow", cuda=False)


def test_auto_without_a_gpu_runs_onnxruntime_without_importing_torch():
    if cuda_device_count():
        pytest.skip("this machine has a CUDA device")
    code = (
        "import sys; from gigan_local.backend_choice import open_model; "
        f"m = open_model({str(DEFAULT_MODEL)!r}, 'auto', threads=1, warmup=0); "
        "print(type(m).__name__, m.backend, 'torch' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=HANG_GUARD_S, check=True
    ).stdout
    assert out.split() == ["GIModel", "onnxruntime", "cpu", "False"]


def test_forced_torch_opens_the_torch_backend():
    model = open_model(DEFAULT_MODEL, "torch", threads=1, warmup=1)
    assert isinstance(model, TorchGIModel) and model.backend.startswith("torch ")


def test_a_model_without_its_architecture_is_a_user_error_on_torch(tmp_path: Path):
    folder = shutil.copytree(DEFAULT_MODEL.parent, tmp_path / "m")
    doc = json.loads((folder / "model.json").read_text())
    del doc["network"]
    (folder / "model.json").write_text(json.dumps(doc))
    with pytest.raises(UserError, match="no generator architecture.*--inference onnxruntime"):
        TorchGIModel(folder / DEFAULT_MODEL.name, threads=1, warmup=0)
    assert GIModel(folder / DEFAULT_MODEL.name, threads=1, warmup=0).backend == "onnxruntime cpu"


def test_a_graph_of_another_resolution_is_refused_on_torch(tmp_path: Path):
    folder = shutil.copytree(DEFAULT_MODEL.parent, tmp_path / "m")
    doc = json.loads((folder / "model.json").read_text())
    (folder / "model.json").write_text(json.dumps(doc | {"resolution": 2 * doc["resolution"]}))
    with pytest.raises(UserError, match="do not belong together"):
        TorchGIModel(folder / DEFAULT_MODEL.name, threads=1, warmup=0)


@pytest.mark.slow
def test_gigan_client_runs_the_model_on_the_backend_asked(make_spec, tmp_path: Path):
    """`gigan-client --inference torch` predicts its GI maps on torch and says so in its summary; an unknown
    backend is one error line."""
    spec_file = tmp_path / "scene.json"
    spec_file.write_text(json.dumps(make_spec(with_box=True).to_dict()))
    resolution = json.loads((DEFAULT_MODEL.parent / "model.json").read_text())["resolution"]
    exe = str(Path(sys.executable).parent / "gigan-client")
    args = ["--scene", str(spec_file), "--frames", "2", "-k", "1", "--resolution", str(resolution)]
    args += ["--gi-source", "model", "--gt-every", "0", "--out", str(tmp_path / "run")]
    proc = subprocess.run([exe, *args, "--inference", "torch"], capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["inference"] == "torch" and summary["config"]["inference"] == "torch"
    bad = subprocess.run([exe, *args, "--inference", "tflite"], capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "auto" in bad.stderr + bad.stdout
