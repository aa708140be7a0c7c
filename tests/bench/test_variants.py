"""`bench variants`: one device's bake against another's, each in its own process. Here the CPU against an earlier
CPU bake of the same maps (a run given as --reference), and CUDA where there is none: the one-line error."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from bench import variant_bench
from bench.runner import execute
from bench.variant_bench import RUNS, VariantsConfig
from gicore.cuda_probe import cuda_device_count
from gicore.error_policy import UserError
from gicore.results import read_rows
from tests.helpers.cloud import write_scenes
from tests.helpers.guards import HANG_GUARD_S


@pytest.mark.slow  # two prebake processes at 32²: about 10 s on 2 idle cores
def test_a_cpu_bake_matches_an_earlier_cpu_bake_of_the_same_maps(tmp_path: Path) -> None:
    scene = str(write_scenes(tmp_path / "scenes") / "ball_moving.json")
    cfg = VariantsConfig(scenes=(scene,), resolution=32, spp=4, maps=3, variants=("cpu",))
    execute(variant_bench.BENCH, cfg, tmp_path / "first", seed=3)
    [first] = read_rows(tmp_path / "first" / "variants.csv")[:1]
    assert (first["system"], first["metric"], first["config"]["source"]) == ("cpu", "mean", "here")
    assert first["config"]["denoiser"] == "oidn" and first["value"] > 0
    assert (tmp_path / "first" / RUNS / "cpu" / "console.txt").read_text().count("mitsuba: ") == 1  # its notice

    again = VariantsConfig(
        scenes=(scene,), resolution=32, spp=4, maps=3, variants=("cpu",), reference=tmp_path / "first"
    )
    again.check()
    files = execute(variant_bench.BENCH, again, tmp_path / "again", seed=3)
    rows = read_rows(tmp_path / "again" / "variants.csv")

    def value(metric: str, stat: str, source: str = "here") -> float:
        [v] = [r["value"] for r in rows if (r["metric"], r["stat"], r["config"]["source"]) == (metric, stat, source)]
        return v

    # the same seeds on the same variant: the same maps, to the float16 the store keeps
    assert value("ssim", "min") == pytest.approx(1.0, abs=1e-6) and value("ssim", "target_met") == 1
    assert value("mean_ratio", "value") == pytest.approx(1.0, abs=1e-4)
    assert value("mean", "mean", "reference") == pytest.approx(first["value"])
    # every map's bake time, the first (the kernels' compile) apart from the others
    assert value("bake", "n") == 2 and value("bake", "first") > 0 and value("bake", "median") > 0
    table = (tmp_path / "again" / "variants.md").read_text()
    assert "llvm_ad_rgb, oidn (reference)" in table or "scalar_rgb, oidn (reference)" in table
    assert "| met |" in table and {p.name for p in files} >= {"variants.csv", "variants.provenance.json", "variants.md"}

    # another seed flies other cameras: the reference refuses it before anything is baked
    with pytest.raises(UserError, match="--seed 4"):
        execute(variant_bench.BENCH, again, tmp_path / "other", seed=4)
    with pytest.raises(UserError, match="baked spp 4, not 8"):
        VariantsConfig(
            scenes=(scene,), resolution=32, spp=8, maps=3, variants=("cpu",), reference=tmp_path / "first"
        ).check()


def test_variant_names_are_checked() -> None:
    for variants, message in ((("gpu",), "not a device"), (("cpu", "cpu"), "names a device twice")):
        with pytest.raises(UserError, match=message):
            VariantsConfig(variants=variants).check()
    with pytest.raises(UserError, match="no variants.provenance.json"):
        VariantsConfig(variants=("cpu",), reference=Path("/nonexistent")).check()


def test_a_cpu_bake_without_pyoidn_is_one_line_naming_the_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pyoidn" else find_spec(name, *a))
    with pytest.raises(
        UserError, match="needs pyoidn, which is not installed: pip install pyoidn, or give --reference"
    ):
        VariantsConfig(variants=("cpu",)).check()


@pytest.mark.skipif(cuda_device_count() > 0, reason="a CUDA device is present")
def test_cuda_without_a_device_is_one_line_before_any_bake(tmp_path: Path) -> None:
    argv = [sys.executable, "-m", "bench", "variants", "--quick", "--variants", "cpu,cuda", "--out", str(tmp_path)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=HANG_GUARD_S)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [
        "error: --variants cuda: GIGAN_MITSUBA_VARIANT=cuda but no CUDA device: bake it on a machine that has one, "
        "or leave it out"
    ]
    assert not (tmp_path / RUNS).exists()
