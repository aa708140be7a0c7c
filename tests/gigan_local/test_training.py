"""Training of gigan_local models on tiny synthetic datasets: learning, budgets, resume, divergence."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from gicore.error_policy import UserError
from gigan_local.config import TrainConfig, read_run_config
from gigan_local.data import FrameDataset
from gigan_local.models import GIGAN, create_model
from gigan_local.preprocess import (
    InputSpec,
    albedo_divisor,
    frame_divisor,
    frame_to_input,
    frame_to_target,
    input_albedo,
    output_to_radiance,
)
from gigan_local.train import METRIC_COLUMNS, TrainingDiverged, load_checkpoint, train
from gigan_local.train_cli import app
from tests.helpers.training import make_dataset, synthetic_frame, tiny_config


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    return make_dataset(tmp_path / "ds")


def read_metrics(run: Path) -> list[dict[str, str]]:
    with (run / "metrics.csv").open() as f:
        return list(csv.DictReader(f))


def test_preprocess_encodings_and_round_trip():
    frame = synthetic_frame(np.random.default_rng(1), 16)
    frame["depth"][:4] = 0.0  # background
    x = frame_to_input(frame, InputSpec(depth_scale=2.0))
    assert x.shape == (10, 16, 16) and x.dtype == np.float32
    assert x.min() >= -1 and x.max() <= 1
    assert np.all(x[9, :4] == -1.0)  # background depth
    frame["depth"][4:] = 2.0
    assert np.allclose(frame_to_input(frame, InputSpec(depth_scale=2.0))[9, 4:], 0.0)
    spec = InputSpec(depth_scale=2.0)
    assert np.allclose(output_to_radiance(frame_to_target(frame, spec), spec), frame["gt"], rtol=1e-3, atol=1e-4)
    frame["di"][0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="'di' contains NaN"):
        frame_to_input(frame, InputSpec())
    with pytest.raises(ValueError, match="cannot be network inputs"):
        InputSpec(buffers=("di", "position"))


def test_a_demodulated_model_sees_and_predicts_shading_and_gives_radiance_back():
    """Albedo demodulation: DI and GT divided by max(albedo, floor) on surfaces, kept where no surface was hit; the
    decoding multiplies the same back, so the round trip gives the GT; the colour of the albedo leaves the input."""
    rng = np.random.default_rng(2)
    frame = synthetic_frame(rng, 16)
    frame["albedo"][:4] = 0.0  # background: no surface
    frame["albedo"][4:8] = (0.9, 0.02, 0.5)  # a saturated colour: its green channel is floored
    spec = InputSpec(depth_scale=2.0, albedo_floor=0.05)
    divisor = albedo_divisor(frame["albedo"], 0.05)
    assert np.all(divisor[:4] == 1.0) and np.allclose(divisor[4, 0], (0.9, 0.05, 0.5))
    target = frame_to_target(frame, spec)
    np.testing.assert_allclose(target, frame_to_target(frame | {"gt": frame["gt"] / divisor}, InputSpec()), atol=1e-6)
    x = frame_to_input(frame, spec)
    np.testing.assert_allclose(x[:3], frame_to_input(frame | {"di": frame["di"] / divisor}, InputSpec())[:3], atol=1e-6)
    np.testing.assert_allclose(input_albedo(x, spec), np.clip(frame["albedo"], 0, 1), atol=1e-6)
    assert np.array_equal(frame_divisor(frame, spec), divisor) and frame_divisor(frame, InputSpec()) is None
    radiance = output_to_radiance(target, spec, divisor)
    np.testing.assert_allclose(radiance, frame["gt"], rtol=1e-3, atol=1e-4)
    # the same light on two colours: the same shading in, the same shading out
    grey = frame | {"albedo": np.full_like(frame["albedo"], 0.5), "gt": frame["gt"] * 0.5, "di": frame["di"] * 0.5}
    blue = frame | {"albedo": np.full_like(frame["albedo"], (0.1, 0.3, 0.9)), "gt": frame["gt"] * (0.1, 0.3, 0.9)}
    blue["di"] = frame["di"] * (0.1, 0.3, 0.9)
    np.testing.assert_allclose(frame_to_target(grey, spec), frame_to_target(blue, spec), atol=1e-5)
    with pytest.raises(ValueError, match="needs the frame's albedo divisor"):
        output_to_radiance(target, spec)
    with pytest.raises(ValueError, match="needs 'albedo' among its input buffers"):
        InputSpec(buffers=("di", "normal"), albedo_floor=0.05)
    assert InputSpec.from_dict({"buffers": ["di", "albedo"], "depth_scale": 1.0}).albedo_floor is None  # old files
    assert InputSpec.from_dict(spec.to_dict()) == spec


def _fixed_batch(n: int, res: int) -> tuple[torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(0)
    frames = [synthetic_frame(rng, res) for _ in range(n)]
    spec = InputSpec(depth_scale=2.0)
    return (
        torch.from_numpy(np.stack([frame_to_input(f, spec) for f in frames])),
        torch.from_numpy(np.stack([frame_to_target(f, spec) for f in frames])),
    )


def test_gigan_halves_l1_on_one_batch():
    torch.manual_seed(0)
    model = create_model(TrainConfig(model="gigan", resolution=32, depth_scale=2.0, ngf=8, ndf=8, batch_size=2))
    model.train()
    batch = _fixed_batch(2, 32)
    first = model.optimize(batch)
    assert set(first) == set(GIGAN.loss_names)
    assert first["D_GP"] > 0  # the penalty is part of the critic step
    for _ in range(120):
        last = model.optimize(batch)
    assert last["G_L1"] < 0.5 * first["G_L1"]


def test_gigan_n_critic_steps_per_generator_step():
    torch.manual_seed(0)
    model = create_model(
        TrainConfig(model="gigan", resolution=32, depth_scale=2.0, ngf=4, ndf=4, batch_size=2, n_critic=2)
    )
    model.train()
    batch = _fixed_batch(2, 32)
    g0 = [p.detach().clone() for p in model.generator.parameters()]
    assert "G_GAN" not in model.optimize(batch)  # critic only
    assert all(torch.equal(a, b) for a, b in zip(g0, model.generator.parameters()))
    assert "G_GAN" in model.optimize(batch)  # critic, then generator
    assert any(not torch.equal(a, b) for a, b in zip(g0, model.generator.parameters()))


def test_critic_warmup_holds_the_generator_for_that_many_critic_steps():
    """critic_warmup 3, n_critic 2: calls 1-4 train the critic only, call 5 is the first generator step,
    then every second call (the period counts from the end of the warm-up)."""
    torch.manual_seed(0)
    cfg = TrainConfig(
        model="gigan", resolution=32, depth_scale=2.0, ngf=4, ndf=4, batch_size=2, n_critic=2, critic_warmup=3
    )
    model = create_model(cfg)
    model.train()
    batch = _fixed_batch(2, 32)
    g0 = [p.detach().clone() for p in model.generator.parameters()]
    d0 = [p.detach().clone() for p in model.nets["D"].parameters()]
    generator_steps = ["G_GAN" in model.optimize(batch) for _ in range(8)]
    assert generator_steps == [False, False, False, False, True, False, True, False]
    assert any(not torch.equal(a, b) for a, b in zip(d0, model.nets["D"].parameters()))
    torch.manual_seed(0)
    held = create_model(cfg)
    held.train()
    for _ in range(4):
        held.optimize(batch)
    assert all(torch.equal(a, b) for a, b in zip(g0, held.generator.parameters()))  # the generator has not moved
    with pytest.raises(ValueError, match="critic_warmup must be >= 0"):
        TrainConfig(critic_warmup=-1)


@pytest.mark.parametrize("name", ["deep_shading", "deep_illumination"])
def test_baselines_take_a_step(name):
    torch.manual_seed(0)
    model = create_model(TrainConfig(model=name, resolution=32, depth_scale=2.0, ngf=4, ndf=4, batch_size=2))
    model.train()
    before = [p.detach().clone() for p in model.generator.parameters()]
    losses = model.optimize(_fixed_batch(2, 32))
    assert set(losses) == set(type(model).loss_names)
    assert all(np.isfinite(v) for v in losses.values())
    assert any(not torch.equal(a, b) for a, b in zip(before, model.generator.parameters()))


def test_train_writes_config_metrics_and_checkpoint(dataset, tmp_path):
    run = tmp_path / "run"
    result = train(tiny_config(dataset, max_steps=3), run, progress=False)
    assert (result.step, result.stop_reason) == (3, "max_steps")
    assert set(result.val_metrics) == {"rmse", "psnr", "ssim", "lf_error"}
    cfg, nets = read_run_config(run)
    assert cfg.resolution == 32 and cfg.depth_scale > 0 and cfg.run_id == "run"
    assert nets["G"].name == "unet" and nets["G"].n_down == 5 and nets["D"].norm == "none"
    assert json.loads((run / "config.json").read_text())["networks"]["G"]["in_channels"] == 10
    rows = read_metrics(run)
    assert tuple(rows[0]) == METRIC_COLUMNS
    val = [r for r in rows if r["split"] == "val"]
    assert {r["step"] for r in val} == {"0", "2", "3"}  # baseline, end of epoch 1 (2 batches), stop
    assert {r["metric"] for r in val} == {"rmse", "psnr", "ssim", "lf_error"}
    assert {r["unit"] for r in val if r["metric"] == "psnr"} == {"dB"} and {
        r["unit"] for r in val if r["metric"] == "lf_error"
    } == {"1"}
    assert {"G_L1", "D_GP", "step_seconds"} <= {r["metric"] for r in rows if r["split"] == "train"}
    assert load_checkpoint(run / "checkpoint.pt")["state"]["step"] == 3
    with pytest.raises(UserError, match="already holds a run: pass --resume"):
        train(tiny_config(dataset, max_steps=3), run, progress=False)


def test_resume_continues_exactly(dataset, tmp_path):
    straight = train(tiny_config(dataset, max_steps=5), tmp_path / "a", progress=False)
    train(tiny_config(dataset, max_steps=3), tmp_path / "b", progress=False)
    resumed = train(tiny_config(dataset, max_steps=5, run_id="b"), tmp_path / "b", resume=True, progress=False)
    assert resumed.step == straight.step == 5
    wa = load_checkpoint(tmp_path / "a" / "checkpoint.pt")["model"]
    wb = load_checkpoint(tmp_path / "b" / "checkpoint.pt")["model"]
    for net in ("G", "D"):
        for k, v in wa["nets"][net].items():
            assert torch.equal(v, wb["nets"][net][k]), f"{net}.{k} differs after resume"
    assert max(int(r["step"]) for r in read_metrics(tmp_path / "b")) == 5
    with pytest.raises(UserError, match="ngf: saved 4 vs given 8"):
        train(tiny_config(dataset, max_steps=6, ngf=8), tmp_path / "b", resume=True, progress=False)


def test_nan_stops_training_with_a_clear_message(dataset, tmp_path, monkeypatch):
    real_optimize = GIGAN.optimize

    def poisoned(self, batch):
        if self.critic_steps == 2:  # third step: corrupt a generator weight
            with torch.no_grad():
                next(self.generator.parameters()).view(-1)[0] = float("nan")
        return real_optimize(self, batch)

    monkeypatch.setattr(GIGAN, "optimize", poisoned)
    with pytest.raises(TrainingDiverged, match=r"step 3: loss \w+ = nan .*checkpoint \(step 2\)"):
        train(tiny_config(dataset, max_steps=10), tmp_path / "run", progress=False)
    assert load_checkpoint(tmp_path / "run" / "checkpoint.pt")["state"]["step"] == 2  # last good one kept


def test_time_budget_stops_cleanly_with_a_checkpoint(dataset, tmp_path):
    result = train(tiny_config(dataset, max_minutes=0.0), tmp_path / "run", progress=False)
    assert (result.stop_reason, result.step) == ("max_minutes", 0)
    assert (tmp_path / "run" / "checkpoint.pt").is_file() and result.val_metrics


def test_crop_training_validates_whole_frames(tmp_path):
    dataset = make_dataset(tmp_path / "ds64", res=64, n_train=2, n_val=1)
    train_set = FrameDataset([dataset], "train", InputSpec(depth_scale=2.0), crop=32, seed=0)
    x, y = train_set[0]
    assert x.shape == (10, 32, 32) and y.shape == (3, 32, 32)
    result = train(tiny_config(dataset, crop=32, max_steps=2), tmp_path / "run", progress=False)
    assert result.step == 2 and result.val_metrics
    _, nets = read_run_config(tmp_path / "run")
    assert nets["G"].n_down == 5  # from the crop; the 64-px validation frames still divide by 32
    with pytest.raises(UserError, match="at least 24 px"):
        train(tiny_config(dataset, crop=16), tmp_path / "run16", progress=False)


def test_frame_cache_returns_the_same_items_and_cannot_be_corrupted(tmp_path):
    dataset = make_dataset(tmp_path / "ds64", res=64, n_train=2, n_val=1)
    spec = InputSpec(depth_scale=2.0)
    plain = FrameDataset([dataset], "train", spec, crop=32, seed=3)
    cached = FrameDataset([dataset], "train", spec, crop=32, seed=3, cache=True)
    whole = FrameDataset([dataset], "train", spec, cache=True)
    for epoch in (0, 1):
        plain.set_epoch(epoch), cached.set_epoch(epoch)
        for i in range(len(plain)):
            for a, b in zip(plain[i], cached[i]):
                assert torch.equal(a, b)
    x, _ = whole[0]
    x.fill_(7.0)  # a caller scribbling on a returned frame must not reach the cache
    assert not torch.equal(whole[0][0], x) and torch.equal(whole[0][0], FrameDataset([dataset], "train", spec)[0][0])


def test_training_with_and_without_the_frame_cache_is_identical(dataset, tmp_path):
    runs = [
        train(tiny_config(dataset, max_steps=3), tmp_path / f"run{c}", progress=False, cache_frames=c)
        for c in (False, True)
    ]
    assert runs[0].val_metrics == runs[1].val_metrics
    weights = [load_checkpoint(r.checkpoint)["model"]["nets"] for r in runs]
    for net, params in weights[0].items():
        for key, value in params.items():
            assert torch.equal(value, weights[1][net][key]), (net, key)


def test_dataset_without_a_needed_buffer_is_refused(dataset, tmp_path):
    with pytest.raises(UserError, match=r"no \['mask'\] buffer"):
        train(tiny_config(dataset, buffers=["di", "mask"]), tmp_path / "run", progress=False)


def test_cli_trains_and_resumes(dataset, tmp_path):
    runner = CliRunner()
    out = tmp_path / "run"
    args = [
        str(dataset),
        "--out",
        str(out),
        "--model",
        "deep_shading",
        "--ngf",
        "4",
        "--batch-size",
        "2",
        "--no-progress",
    ]
    res = runner.invoke(app, [*args, "--max-steps", "1"])
    assert res.exit_code == 0, res.output
    assert "stopped (max_steps) at step 1" in res.output
    # The saved --max-steps 1 bounded the first invocation only; this one runs to the end of epoch 2.
    res = runner.invoke(app, ["--out", str(out), "--resume", "--epochs", "2", "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "stopped (epochs) at step 4" in res.output
    # Refusals are user errors (their exit status and one-line message: tests/integration/test_cli_errors.py).
    res = runner.invoke(app, ["--out", str(out), "--resume", "--ngf", "8"])
    assert isinstance(res.exception, UserError) and "--resume may change only" in str(res.exception)
    res = runner.invoke(app, ["--out", str(tmp_path / "new")])
    assert isinstance(res.exception, UserError) and "no dataset folders given" in str(res.exception)
    assert not (tmp_path / "new").exists()


def test_cuda_without_a_gpu_is_one_user_error_before_any_file(dataset, tmp_path, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(UserError, match="--device cuda: torch .* sees no CUDA GPU.*--device cpu"):
        train(tiny_config(dataset, device="cuda"), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()
    with pytest.raises(ValueError, match=r"device must be one of \['cpu', 'cuda'\]"):
        tiny_config(dataset, device="tpu")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU; CI has none")
def test_a_cuda_run_resumes_on_the_cpu(dataset, tmp_path):
    gpu = train(tiny_config(dataset, max_steps=2, device="cuda"), tmp_path / "run", progress=False)
    assert gpu.step == 2 and np.isfinite(gpu.val_metrics["ssim"])
    assert read_run_config(tmp_path / "run")[0].device == "cuda"
    raw = torch.load(gpu.checkpoint, weights_only=True)  # no map_location: tensors return where they were saved
    assert next(iter(raw["model"]["nets"]["G"].values())).device.type == "cuda" and "cuda_rng" in raw
    cpu = train(tiny_config(dataset, max_steps=4, run_id="run"), tmp_path / "run", resume=True, progress=False)
    assert cpu.step == 4 and read_run_config(tmp_path / "run")[0].device == "cpu"
    assert next(iter(torch.load(cpu.checkpoint, weights_only=True)["model"]["nets"]["G"].values())).device.type == "cpu"
