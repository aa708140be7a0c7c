"""ONNX export (fp32 / fp16 weights) and the onnxruntime client GIModel."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from typer.testing import CliRunner

from gicore.buffers import CHANNELS
from gicore.dataset import load_frame
from gicore.error_policy import UserError
from gigan_local.config import NetworkConfig
from gigan_local.export import export_onnx, load_generator
from gigan_local.export_cli import app
from gigan_local.inference import GIModel
from gigan_local.networks import define_G
from gigan_local.preprocess import InputSpec, frame_to_input, output_to_radiance
from gigan_local.train import train
from gigan_local.warmstart import load_into
from tests.helpers.training import make_dataset, tiny_config


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(dataset, run folder, export folder) of a briefly trained ngf-16 GIGAN at 32 px."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        root = tmp_path_factory.mktemp("gigan_export")
        dataset = make_dataset(root / "ds")
        run = root / "run"
        train(tiny_config(dataset, ngf=16, max_steps=2), run, progress=False)
        result = CliRunner().invoke(app, [str(run), "--out", str(root / "onnx")])
    finally:
        torch.set_num_threads(threads)
    assert result.exit_code == 0, result.output
    return dataset, run, root / "onnx"


def test_onnx_fp32_matches_torch(exported):
    _, run, onnx_dir = exported
    generator, _ = load_generator(run)
    x = np.random.default_rng(3).uniform(-1, 1, (2, 10, 32, 32)).astype(np.float32)  # batch 2: dynamic batch axis
    with torch.no_grad():
        ref = generator(torch.from_numpy(x)).numpy()
    out = ort.InferenceSession(str(onnx_dir / "model_fp32.onnx"), providers=["CPUExecutionProvider"]).run(
        None, {"input": x}
    )[0]
    assert np.abs(out - ref).max() < 1e-4
    out16 = ort.InferenceSession(str(onnx_dir / "model_fp16.onnx"), providers=["CPUExecutionProvider"]).run(
        None, {"input": x}
    )[0]
    assert out16.dtype == np.float32 and np.abs(out16 - ref).max() < 1e-2


def test_fp16_file_is_about_half_the_size(exported):
    _, _, onnx_dir = exported
    ratio = (onnx_dir / "model_fp16.onnx").stat().st_size / (onnx_dir / "model_fp32.onnx").stat().st_size
    assert 0.45 < ratio < 0.55


def test_model_json_describes_the_model(exported):
    _, run, onnx_dir = exported
    doc = json.loads((onnx_dir / "model.json").read_text())
    assert doc["input"]["buffers"] == ["di", "albedo", "normal", "depth"]
    assert (doc["in_channels"], doc["resolution"], doc["ngf"], doc["n_down"]) == (10, 32, 16, 5)
    assert doc["files"] == {"fp32": "model_fp32.onnx", "fp16": "model_fp16.onnx"}
    assert "tonemap" in doc["tonemap"] and doc["opset"] >= 17


@pytest.mark.parametrize("variant", ["model_fp32.onnx", "model_fp16.onnx"])
def test_gimodel_predicts_linear_radiance_like_torch(exported, variant):
    dataset, run, onnx_dir = exported
    model = GIModel(onnx_dir / variant, threads=1)
    frame = load_frame(dataset / "val" / "000000.npz")
    radiance = model.predict(frame)
    assert radiance.shape == (32, 32, 3) and radiance.dtype == np.float32
    assert np.all(np.isfinite(radiance)) and radiance.min() >= 0
    generator, _ = load_generator(run)
    with torch.no_grad():
        y = generator(torch.from_numpy(frame_to_input(frame, model.spec))[None])[0].numpy()
    assert np.allclose(radiance, output_to_radiance(y, model.spec), rtol=1e-2, atol=1e-3)


def test_int8_export_is_calibrated_quantized_and_close_to_fp32(exported, tmp_path):
    dataset, run, _ = exported
    result = CliRunner().invoke(
        app, [str(run), "--out", str(tmp_path / "q"), "--int8", "--calibration-frames", "2", "--no-fp16"]
    )
    assert result.exit_code == 0, result.output
    doc = json.loads((tmp_path / "q" / "model.json").read_text())
    assert doc["files"] == {"fp32": "model_fp32.onnx", "int8": "model_int8.onnx"}
    assert doc["int8"]["calibration_frames"] == 2 and 0 < doc["int8"]["mean_abs_diff_vs_fp32_on_val"] < 0.05
    ops = {n.op_type for n in onnx.load(str(tmp_path / "q" / "model_int8.onnx")).graph.node}
    assert "QLinearConv" in ops  # really quantized, not a renamed fp32 graph
    assert sorted(p.name for p in (tmp_path / "q").iterdir()) == ["model.json", "model_fp32.onnx", "model_int8.onnx"]
    frame = load_frame(dataset / "val" / "000000.npz")
    q, f = (
        GIModel(tmp_path / "q" / "model_int8.onnx", threads=1).predict(frame),
        GIModel(tmp_path / "q" / "model_fp32.onnx", threads=1).predict(frame),
    )
    assert np.abs(q - f).mean() < 0.05 * max(float(f.mean()), 1e-3) + 1e-3


def test_int8_export_without_the_training_data_says_so(exported, tmp_path):
    _, run, _ = exported
    moved = _copy(run, tmp_path / "run")
    cfg = json.loads((moved / "config.json").read_text())
    cfg["train"]["datasets"] = [str(tmp_path / "gone")]
    (moved / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(UserError, match="int8 export calibrates on the run's train frames.*--int8"):
        export_onnx(moved, tmp_path / "q", int8=True)


def test_inference_path_does_not_import_torch():
    code = "import sys, gigan_local.inference; assert 'torch' not in sys.modules, 'torch was imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


def _copy(onnx_dir: Path, dst: Path) -> Path:
    shutil.copytree(onnx_dir, dst)
    return dst


def test_missing_files_give_clear_errors(exported, tmp_path):
    _, _, onnx_dir = exported
    with pytest.raises(UserError, match=r"nope\.onnx is missing.*gigan-export"):
        GIModel(tmp_path / "nope.onnx")
    d = _copy(onnx_dir, tmp_path / "m")
    (d / "model.json").unlink()
    with pytest.raises(UserError, match="model.json is missing"):
        GIModel(d / "model_fp32.onnx")


def test_corrupt_model_file_gives_a_clear_error(exported, tmp_path):
    _, _, onnx_dir = exported
    d = _copy(onnx_dir, tmp_path / "m")
    (d / "model_fp32.onnx").write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(UserError, match=r"model_fp32\.onnx is not a loadable ONNX model.*gigan-export"):
        GIModel(d / "model_fp32.onnx")
    (d / "model.json").write_text("{not json")
    with pytest.raises(UserError, match=r"model\.json is not a valid gigan model config"):
        GIModel(d / "model_fp16.onnx")


@pytest.mark.parametrize(
    ("field", "value"), [("input", {"buffers": ["di", "albedo"], "depth_scale": 1.0}), ("resolution", 64)]
)
def test_model_and_config_mismatch_gives_a_clear_error(exported, tmp_path, field, value):
    _, _, onnx_dir = exported
    d = _copy(onnx_dir, tmp_path / "m")
    doc = json.loads((d / "model.json").read_text())
    (d / "model.json").write_text(json.dumps(doc | {field: value}))
    with pytest.raises(UserError, match="do not belong together"):
        GIModel(d / "model_fp32.onnx")


def test_frame_of_the_wrong_size_or_buffers_is_refused(exported):
    dataset, _, onnx_dir = exported
    model = GIModel(onnx_dir / "model_fp32.onnx", threads=1, warmup=0)
    frame = load_frame(dataset / "val" / "000000.npz")
    with pytest.raises(ValueError, match="model runs at 32x32"):
        model.predict({k: v[:16, :16] for k, v in frame.items()})
    with pytest.raises(KeyError, match="depth"):
        model.predict({k: v for k, v in frame.items() if k != "depth"})


def test_deep_shading_exports_too(exported, tmp_path):
    dataset, _, _ = exported
    train(tiny_config(dataset, model="deep_shading", max_steps=1), tmp_path / "run", progress=False)
    result = export_onnx(tmp_path / "run", tmp_path / "onnx", fp16=False)
    assert set(result.files) == {"fp32"} and result.max_abs_diff["fp32"] < 1e-4
    assert GIModel(result.files["fp32"], threads=1).predict(load_frame(dataset / "val" / "000001.npz")).shape == (
        32,
        32,
        3,
    )


def test_wheel_ships_the_default_model_and_scenes(tmp_path):
    """A non-editable install must find the shipped model: build the wheel (from a copy of the sources,
    so no build/ folder lands in the checkout) and list it (``models/*`` once matched no file)."""
    import zipfile

    from gigan_local.inference import DEFAULT_MODEL

    repo = Path(__file__).resolve().parents[2]
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(repo / name, src / name)
    for package in ("gicore", "gigan_local", "baseline_cloudbaking", "network_sim", "bench"):
        shutil.copytree(repo / package, src / package, ignore=shutil.ignore_patterns("__pycache__"))
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "wheel",
        "-q",
        "--no-deps",
        "--no-build-isolation",
        "-w",
        str(tmp_path / "dist"),
        str(src),
    ]
    subprocess.run(cmd, check=True, timeout=300, capture_output=True)
    (wheel,) = (tmp_path / "dist").glob("*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    model_dir = DEFAULT_MODEL.parent.relative_to(repo).as_posix()
    for path in DEFAULT_MODEL.parent.iterdir():  # model_fp16.onnx, model_fp32.onnx, model.json, MODEL_CARD.md
        assert f"{model_dir}/{path.name}" in names, f"{path.name} is missing from the wheel"
    assert {f"gicore/scenes/{p.name}" for p in (repo / "gicore" / "scenes").glob("*.toml")} <= names


def test_the_shipped_model_card_matches_its_files() -> None:
    """MODEL_CARD.md beside the shipped model states the files' sizes, the architecture and the step of
    the exported weights: each must be what the files and model.json say."""
    import re

    from gigan_local.inference import DEFAULT_MODEL
    from gigan_local.model_card import UPSAMPLING_WORDS

    folder = DEFAULT_MODEL.parent
    card = (folder / "MODEL_CARD.md").read_text()
    doc = json.loads((folder / "model.json").read_text())
    upsampling = UPSAMPLING_WORDS[doc["network"].get("upsample", "transposed")]
    assert f"ngf {doc['ngf']}, {doc['n_down']} down-samplings, {upsampling}" in card
    assert f"Stopped at optimizer step {doc['step']} " in card
    listed = dict(re.findall(r"- `(model_\w+\.onnx)`: \w+ weights, ([\d.]+) MiB", card))
    assert set(listed) == {p.name for p in folder.glob("*.onnx")}
    for name, mib in listed.items():
        assert f"{(folder / name).stat().st_size / 2**20:.2f}" == mib, name


def test_the_diagnosis_variant_trains_exports_and_runs_like_torch(tmp_path):
    """Resize up-sampling (nearest 2x + 3x3 conv, exported as sub-pixel phase convolutions) and an
    unconditional critic: the run trains, its config records both, the exported model computes what torch
    does (and quantizes to int8), and a warm start (`--init-generator`) reads it back: the 3x3 kernels the
    phase kernels are computed from, and the batch norms the exporter folded into the down and the resize up
    convolutions."""
    dataset = make_dataset(tmp_path / "ds")
    run = tmp_path / "run"
    train(tiny_config(dataset, max_steps=2, upsample="resize", critic_condition=False), run, progress=False)
    config = json.loads((run / "config.json").read_text())
    assert config["networks"]["G"]["upsample"] == "resize" and config["networks"]["D"]["in_channels"] == 0
    args = [str(run), "--out", str(tmp_path / "onnx"), "--no-fp16", "--int8", "--calibration-frames", "2"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    int8_ops = {n.op_type for n in onnx.load(str(tmp_path / "onnx" / "model_int8.onnx")).graph.node}
    assert {"QLinearConv", "DepthToSpace"} <= int8_ops  # the phase kernels folded and quantized too
    generator, _ = load_generator(run)
    x = np.random.default_rng(4).uniform(-1, 1, (1, 10, 32, 32)).astype(np.float32)
    with torch.no_grad():
        ref = generator(torch.from_numpy(x)).numpy()
    session = ort.InferenceSession(str(tmp_path / "onnx" / "model_fp32.onnx"), providers=["CPUExecutionProvider"])
    ops = {n.op_type for n in onnx.load(str(tmp_path / "onnx" / "model_fp32.onnx")).graph.node}
    assert {"DepthToSpace", "Resize"} <= ops  # 32 px: sub-pixel convolutions on the 8 and 16 px inputs only
    assert np.abs(session.run(None, {"input": x})[0] - ref).max() < 1e-4
    doc = json.loads((tmp_path / "onnx" / "model.json").read_text())
    net, spec = NetworkConfig.from_dict(doc["network"]), InputSpec.from_dict(doc["input"])
    warm = define_G(net)
    # folded: downs 1 .. n-2 and every up layer but the outermost (which has no batch norm)
    assert load_into(warm, tmp_path / "onnx" / "model_fp32.onnx", net, spec, None) == 2 * net.n_down - 3
    with torch.no_grad():
        assert np.abs(warm.eval()(torch.from_numpy(x)).numpy() - ref).max() < 1e-4


def test_a_resized_export_runs_the_same_network_at_the_new_side(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """The shipped 256² model at 512² (python -m gigan_local.resize_cli, in this process): onnxruntime matches torch
    on the same weights there, the client's GIModel predicts 512² maps with it, and model.json says where it was
    trained; a side the U-Net cannot take is one error line."""
    from unittest import mock

    from gigan_local import resize_cli
    from gigan_local.inference import DEFAULT_MODEL

    out = tmp_path / "m512"

    def resize(side: int) -> int:
        argv = ["resize_cli", str(DEFAULT_MODEL.parent), "--out", str(out), "--resolution", str(side)]
        with mock.patch.object(sys, "argv", argv), pytest.raises(SystemExit) as exited:
            resize_cli.main()
        return int(exited.value.code or 0)

    assert resize(512) == 0, capfd.readouterr().err
    doc = json.loads((out / "model.json").read_text())
    assert (doc["resolution"], doc["trained_resolution"], set(doc["files"])) == (512, 256, {"fp32", "fp16"})
    assert max(doc["max_abs_diff_vs_torch"].values()) <= 1e-3
    model = GIModel(out / "model_fp16.onnx", threads=1, warmup=0)
    rng = np.random.default_rng(0)
    frame = {b: rng.random((512, 512, CHANNELS[b]), dtype=np.float32) for b in model.buffers}
    assert model.predict(frame).shape == (512, 512, 3)
    capfd.readouterr()
    assert resize(300) == 2
    err = capfd.readouterr().err
    assert "use a multiple of 256" in err and len(err.strip().splitlines()) == 1
