"""Tiny real runs of the benches: ``bench render`` through the command line (what it prints, writes and plots),
convergence, training curves, warp, frequency and fov at a few frames of 16-32 px (the ``--quick`` chain of a
fresh checkout: tests/bench/test_fresh_checkout.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.runner import execute
from gicore.results import read_rows
from tests.helpers.cli import exit_status


def test_tiny_render_run_through_the_command(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    options = [
        "--resolution",
        "16",
        "--repeats",
        "1",
        "--gt-repeats",
        "1",
        "--gl-resolutions",
        "16",
        "--gl-repeats",
        "1",
    ]
    code = exit_status(["bench", "render", "--quick", *options, "--out", str(tmp_path)])
    out, err = capsys.readouterr()
    assert code == 0, err
    written = ["render.csv", "render.provenance.json", "render.md", "render.png", "render.svg"]
    lines, table = out.split("\n\n", 1)  # every file written, then the tables the run wrote
    assert lines.split() == [word for name in written for word in ("wrote", str(tmp_path / name))]
    assert table.strip() == (tmp_path / "render.md").read_text().strip()
    rows = read_rows(tmp_path / "render.csv")
    assert {r["metric"] for r in rows} >= {"triangles", "di_1spp", "gt_256spp"}
    assert any(r["config"].get("pass_set") == "client" for r in rows)
    prov = json.loads((tmp_path / "render.provenance.json").read_text())
    assert {"scenes": ["lung_plane"], "resolution": 16, "repeats": 1, "gt_repeats": 1}.items() <= prov[
        "settings"
    ].items()
    assert (tmp_path / "render.png").stat().st_size > 10_000
    assert ">gt_256spp</text>" in (tmp_path / "render.svg").read_text()  # each pass a series of bars


def test_tiny_convergence_run_writes_csv_and_plot(tmp_path: Path) -> None:
    from bench.convergence import BENCH, ConvergenceConfig

    cfg = ConvergenceConfig(scenes=("lung_plane",), resolution=16, spps=(1, 4), reference_spp=16, repeats=1)
    execute(BENCH, cfg, tmp_path)
    rows = read_rows(tmp_path / "convergence.csv")
    assert (tmp_path / "convergence.png").stat().st_size > 0
    assert ">lung_plane (path+oidn)</text>" in (tmp_path / "convergence.svg").read_text()
    rmse = {(r["system"], r["config"]["spp"]): r["value"] for r in rows if r["metric"] == "rmse"}
    assert set(rmse) == {("path", 1), ("path", 4), ("path+oidn", 1), ("path+oidn", 4)}
    assert rmse[("path", 4)] < rmse[("path", 1)]  # more samples, less error against the reference


def test_training_curves_from_run_folders(tmp_path: Path) -> None:
    from bench.training import BENCH, TrainingBenchConfig

    run_dir = tmp_path / "runA"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps({"train": {"ngf": 8, "n_critic": 5}}))
    (run_dir / "metrics.csv").write_text(
        "run_id,model,epoch,step,split,metric,value,unit\nx,gigan,0,0,val,ssim,0.5,1\nx,gigan,1,10,train,G_L1,0.2,1\nx,gigan,1,10,train,step_seconds,0.5,s\nx,gigan,1,10,val,ssim,0.7,1\n"
    )
    execute(BENCH, TrainingBenchConfig(runs=(run_dir,)), tmp_path / "out")
    rows = read_rows(tmp_path / "out" / "training.csv")
    assert {(r["system"], r["metric"], r["config"]["step"]) for r in rows} == {
        ("runA", "val_ssim", 0),
        ("runA", "train_G_L1", 10),
        ("runA", "train_step_seconds", 10),
        ("runA", "val_ssim", 10),
    }
    assert (tmp_path / "out" / "training.png").stat().st_size > 0
    assert ">runA</text>" in (tmp_path / "out" / "training.svg").read_text()  # the run's curve, in the legend


@pytest.mark.slow
def test_tiny_warp_frequency_and_fov_runs(tmp_path: Path) -> None:
    """The three client benches end to end at 32², a few frames each: CSV, plots, and a sanity bound each."""
    from bench import fov, frequency, warp_bench

    cfg = warp_bench.WarpBenchConfig(
        scenes=("lung_plane",), resolution=32, gi_frames=(0,), offsets=(1, 5), spp=4, repeats=1, warmup=0
    )
    execute(warp_bench.BENCH, cfg, tmp_path / "warp")
    rows = read_rows(tmp_path / "warp" / "warp.csv")
    assert {r["system"] for r in rows if r["metric"] == "ssim" and r["stat"] == "mean"} == {
        "structure-aware",
        "pixel-level",
    }
    assert all(0 < r["value"] <= 1 for r in rows if r["metric"] == "valid_fraction")

    cfg = frequency.FrequencyConfig(resolution=32, ks=(1, 10), frames=12, gt_every=6, spp=4, compositions=("blend",))
    paths = execute(frequency.BENCH, cfg, tmp_path / "frequency")
    fps = {(r["system"], r["config"]["k"]): r["value"] for r in read_rows(paths[0]) if r["metric"] == "fps"}
    assert fps["structure-aware", 10] > fps["structure-aware", 1]  # the GI map's cost spread over 10 frames
    quality = {
        (r["system"], r["config"]["k"], r["metric"]): r["value"] for r in read_rows(paths[0]) if r["stat"] == "mean"
    }
    for (system, k), _ in fps.items():  # the low-frequency error beside SSIM and PSNR, at most RMSE = 10^(-PSNR/20)
        assert 0 < quality[system, k, "lf_error"] <= 10 ** (-quality[system, k, "psnr"] / 20), (system, k)
    table = (tmp_path / "frequency" / "frequency.md").read_text()
    assert "| 10 |" in table and "| LF error (structure-aware) |" in table
    assert "lung_plane: structure-aware (blend)" in (tmp_path / "frequency" / "frequency.svg").read_text()

    cfg = fov.FovConfig(
        resolution=32, gi_fovs=(60.0, 90.0), base_frames=(0,), rotations=(10.0,), translations=(0.2,), spp=4
    )
    paths = execute(fov.BENCH, cfg, tmp_path / "fov")
    valid = {
        r["config"]["gi_fov"]: r["value"]
        for r in read_rows(paths[0])
        if r["metric"] == "valid_fraction" and r["system"] == "structure-aware" and r["config"]["motion"] == "rotation"
    }
    assert valid[90.0] >= valid[60.0]  # a wider GI camera still covers the turned view
    assert all(p.is_file() for p in paths) and (tmp_path / "fov" / "fov.png").is_file()
    assert "lung_plane: structure-aware, F_GI 90°" in (tmp_path / "fov" / "fov.svg").read_text()  # a declared series
