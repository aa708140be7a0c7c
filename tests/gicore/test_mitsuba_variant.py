"""Mitsuba's variant and the GT denoiser: the choice as a pure function of what was asked and what the machine
has, what a machine without CUDA gets, and the one-line refusal of a CUDA variant it cannot run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gicore import mitsuba_variant
from gicore.cuda_probe import cuda_device_count
from gicore.error_policy import UserError
from gicore.mitsuba_variant import VARIANT_ENV, VariantChoice, check_denoiser, choose_variant
from tests.helpers.guards import HANG_GUARD_S

LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"


@pytest.mark.parametrize(
    ("asked", "devices", "built", "variant", "denoiser", "reason"),
    [
        ("auto", 1, True, "cuda_ad_rgb", "optix", "auto; GIGAN_MITSUBA_VARIANT=cpu|cuda forces one"),
        ("cuda", 2, True, "cuda_ad_rgb", "optix", "GIGAN_MITSUBA_VARIANT=cuda"),
        ("auto", 0, True, "llvm_ad_rgb", "oidn", "no CUDA device"),
        ("auto", 1, False, "llvm_ad_rgb", "oidn", "no cuda_ad_rgb built"),
        ("cpu", 1, True, "llvm_ad_rgb", "oidn", "GIGAN_MITSUBA_VARIANT=cpu"),
    ],
)
def test_the_cuda_variant_where_it_runs_else_the_cpu_one(asked, devices, built, variant, denoiser, reason):
    choice = choose_variant(asked, devices, built, LLVM)
    assert (choice.variant, choice.denoiser) == (variant, denoiser)
    assert choice.notice.startswith(f"mitsuba: {variant} ") and choice.notice.endswith(f"({reason})")
    assert "\n" not in choice.notice


@pytest.mark.parametrize("asked", ["auto", "cuda"])
def test_without_the_optix_weights_oidn_denoises_on_the_gpu(asked):
    choice = choose_variant(asked, 1, True, LLVM, optix_weights=False)
    assert (choice.variant, choice.denoiser, choice.needs_pyoidn) == ("cuda_ad_rgb", "oidn-cuda", True)
    assert "OIDN denoiser on the GPU" in choice.notice and "nvoptix.bin" in choice.notice
    assert "\n" not in choice.notice
    assert choose_variant("cpu", 1, True, LLVM, optix_weights=False).denoiser == "oidn"
    # a torch without CUDA (the project's CPU wheel) cannot hand OIDN device tensors: OIDN runs on the CPU
    on_cpu = choose_variant(asked, 1, True, LLVM, optix_weights=False, torch_cuda=False)
    assert (on_cpu.variant, on_cpu.denoiser) == ("cuda_ad_rgb", "oidn") and "OIDN denoiser on the CPU" in on_cpu.notice


def test_without_llvm_the_cpu_variant_is_scalar_and_the_notice_says_how_to_fix_it():
    choice = choose_variant("auto", 0, True, None)
    assert (choice.variant, choice.denoiser) == ("scalar_rgb", "oidn")
    assert "45x slower" in choice.notice and "apt-get install libllvm19" in choice.notice


@pytest.mark.parametrize(
    ("asked", "devices", "built", "message"),
    [
        ("cuda", 0, True, "GIGAN_MITSUBA_VARIANT=cuda but no CUDA device: set GIGAN_MITSUBA_VARIANT=cpu or auto"),
        ("cuda", 1, False, "GIGAN_MITSUBA_VARIANT=cuda but this Mitsuba build has no cuda_ad_rgb: set"),
        ("cuda_ad_rgb", 1, True, "GIGAN_MITSUBA_VARIANT='cuda_ad_rgb' is not a device: set it to one of auto, cpu"),
    ],
)
def test_a_variant_that_cannot_run_is_a_user_error(asked, devices, built, message):
    with pytest.raises(UserError) as refused:
        choose_variant(asked, devices, built, LLVM)
    assert str(refused.value).startswith(message)


def test_optix_denoises_without_pyoidn_oidn_needs_it(monkeypatch):
    monkeypatch.setattr(mitsuba_variant.importlib.util, "find_spec", lambda name: None)
    for denoiser in ("optix", "oidn", "oidn-cuda"):
        monkeypatch.setattr(mitsuba_variant, "mitsuba_choice", lambda d=denoiser: VariantChoice("v", d, "n"))
        check_denoiser(False)
        if denoiser == "optix":
            check_denoiser(True)
        else:
            with pytest.raises(UserError, match="needs pyoidn"):
                check_denoiser(True)


def _env(asked: str | None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != VARIANT_ENV}
    return env if asked is None else env | {VARIANT_ENV: asked}


@pytest.mark.skipif(cuda_device_count() > 0, reason="this machine has a CUDA device")
@pytest.mark.parametrize("asked", [None, "auto", "cpu"])
def test_without_cuda_the_cpu_variant_is_chosen_with_one_notice(asked):
    code = "import gicore.render as r; print(r.VARIANT, r.CHOICE.denoiser)"
    proc = subprocess.run(
        [sys.executable, "-c", code], env=_env(asked), capture_output=True, text=True, timeout=HANG_GUARD_S
    )
    assert proc.returncode == 0, proc.stderr
    variant = proc.stdout.split()[0]
    assert variant in ("llvm_ad_rgb", "scalar_rgb") and proc.stdout.split()[1] == "oidn"
    [notice] = proc.stderr.splitlines()
    reason = "GIGAN_MITSUBA_VARIANT=cpu" if asked == "cpu" else "no CUDA device"
    assert notice.startswith(f"mitsuba: {variant} ") and reason in notice


@pytest.mark.skipif(cuda_device_count() > 0, reason="this machine has a CUDA device")
def test_forcing_cuda_without_it_is_one_error_line(make_spec, tmp_path: Path):
    spec_file = tmp_path / "scene.json"
    spec_file.write_text(json.dumps(make_spec().to_dict()))
    exe = str(Path(sys.executable).parent / "gigan-client")
    args = ["--scene", str(spec_file), "--frames", "1", "--resolution", "16", "--gi-source", "gt", "--no-denoise"]
    proc = subprocess.run(
        [exe, *args, "--out", str(tmp_path / "run")],
        env=_env("cuda"),
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    [line] = [x for x in proc.stderr.splitlines() if x.strip()]
    assert line.startswith("error: GIGAN_MITSUBA_VARIANT=cuda but no CUDA device: set GIGAN_MITSUBA_VARIANT=cpu")
    assert not (tmp_path / "run" / "frames.csv").exists()
