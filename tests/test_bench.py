"""The bench framework: CLI wiring, config presets, tidy CSV + provenance, and a tiny real bench run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bench.cli import _config, app
from bench.convergence import ConvergenceConfig, run
from gicore.results import COLUMNS, Results, read_rows
from gicore.timing import summarize_ms, time_repeats

SUBCOMMANDS = ("convergence", "render", "warp", "frequency", "fov", "quality", "training", "run-default")


@pytest.mark.parametrize("name", SUBCOMMANDS)
def test_every_subcommand_parses_and_documents_out_and_quick(name: str) -> None:
    result = CliRunner().invoke(app, [name, "--help"])
    assert result.exit_code == 0, result.output
    assert "--out" in result.output
    if name not in ("run-default", "training"):
        assert "--quick" in result.output


def test_config_applies_preset_then_only_given_options() -> None:
    cfg = _config(ConvergenceConfig, True, scenes="lung_plane, vessels_plane", resolution=None)
    assert cfg.scenes == ("lung_plane", "vessels_plane")
    assert cfg.resolution == ConvergenceConfig.quick().resolution  # None leaves the preset's value
    assert _config(ConvergenceConfig, False, resolution=64).spps == ConvergenceConfig().spps


def test_results_are_tidy_with_provenance(tmp_path: Path) -> None:
    res = Results("demo", tmp_path, seed=3, settings={"k": 1})
    res.add(system="a", scene="s", metric="ssim", value=0.5, unit="1", spp=4)
    res.add_timing(system="a", scene="s", metric="t", samples_s=[0.001, 0.002, 0.003])
    rows = read_rows(res.write())
    assert list(rows[0]) == list(COLUMNS)
    assert rows[0]["config"] == {"spp": 4} and rows[0]["value"] == 0.5
    assert {(r["stat"], r["value"]) for r in rows if r["metric"] == "t"} >= {("median", 2.0), ("n", 3.0)}
    prov = json.loads((tmp_path / "demo.provenance.json").read_text())
    assert prov["seed"] == 3 and prov["rows"] == 4 and {"sha", "dirty"} <= set(prov["git"]) and prov["versions"]["numpy"]


def test_timing_warms_up_and_summarises() -> None:
    calls = []
    samples, result = time_repeats(lambda: calls.append(1) or len(calls), repeats=3, warmup=2)
    assert len(samples) == 3 and len(calls) == 5 and result == 5
    assert summarize_ms([0.001, 0.003])["median"] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="repeats"):
        time_repeats(lambda: None, repeats=0)


def test_tiny_convergence_run_writes_csv_and_plot(tmp_path: Path) -> None:
    cfg = ConvergenceConfig(scenes=("lung_plane",), resolution=16, spps=(1, 4), reference_spp=16, repeats=1)
    rows = read_rows(run(cfg, tmp_path))
    assert (tmp_path / "convergence.png").stat().st_size > 0
    rmse = {(r["system"], r["config"]["spp"]): r["value"] for r in rows if r["metric"] == "rmse"}
    assert set(rmse) == {("path", 1), ("path", 4), ("path+oidn", 1), ("path+oidn", 4)}
    assert rmse[("path", 4)] < rmse[("path", 1)]  # more samples, less error against the reference


def test_training_minutes_sum_the_logged_step_times() -> None:
    from bench.training import training_minutes

    # 10 steps at 6 s, then 20 at 3 s; step 40 extrapolates at the last rate.
    assert training_minutes([(10, 6.0), (30, 3.0)], [0, 5, 10, 30, 40]) == pytest.approx([0, 0.5, 1.0, 2.0, 2.5])


def test_training_curves_from_run_folders(tmp_path: Path) -> None:
    from bench.training import run as run_training

    run_dir = tmp_path / "runA"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps({"train": {"ngf": 8, "n_critic": 5}}))
    (run_dir / "metrics.csv").write_text(
        "run_id,model,epoch,step,split,metric,value,unit\nx,gigan,0,0,val,ssim,0.5,1\nx,gigan,1,10,train,G_L1,0.2,1\nx,gigan,1,10,train,step_seconds,0.5,s\nx,gigan,1,10,val,ssim,0.7,1\n"
    )
    rows = read_rows(run_training([run_dir], tmp_path / "out"))
    assert {(r["system"], r["metric"], r["config"]["step"]) for r in rows} == {
        ("runA", "val_ssim", 0), ("runA", "train_G_L1", 10), ("runA", "train_step_seconds", 10), ("runA", "val_ssim", 10)
    }
    assert (tmp_path / "out" / "training.png").stat().st_size > 0
    with pytest.raises(FileNotFoundError, match="metrics.csv"):
        run_training([tmp_path], tmp_path / "out2")
