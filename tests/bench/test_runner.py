"""The bench framework: the runner (options from configs, presets, checks, --out), tidy CSV + provenance,
and tiny real bench runs through the ``bench`` command."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest
import typer
from typer.testing import CliRunner

from bench.cli import app
from bench.present.declarations import Chart, Column, Figure, Table, pick
from bench.runner import Bench, build_config, execute, field_docs, register
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.results import COLUMNS, Results, read_rows
from gicore.timing import summarize_ms, time_repeats

REPO = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class DemoConfig:
    """A config exercising every field form the runner supports."""

    scenes: tuple[str, ...] = option_groups.scenes()  # a shared option, composed (each scene must load)
    #: Square resolution in pixels.
    resolution: int = 64
    #: A threshold that may be zero.
    tau: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})
    #: Denoise or not.
    denoise: bool = True
    #: Which warp.
    warp: Literal["structure", "pixel"] = "structure"
    #: Optional cost in ms.
    cost_ms: float | None = None
    #: Named files.
    models: dict[str, Path] = field(default_factory=lambda: {"a": Path("a.onnx")})
    #: Frame indices (0 allowed).
    frames: tuple[int, ...] = field(default=(0, 5), metadata={"min": 0})

    @classmethod
    def quick(cls) -> DemoConfig:
        return cls(resolution=16, denoise=False)


def _demo_measure(cfg: DemoConfig, res: Results) -> None:
    res.add(system="demo", scene=cfg.scenes[0], metric="resolution", value=cfg.resolution, unit="px")
    res.output("note.md").write_text("a table")


DEMO = Bench(
    "demo",
    DemoConfig,
    _demo_measure,
    help="A demo bench.",
    parts=(
        Table(pick("resolution"), (Column("scene", "{scene}"), Column("px", "{value:g}"))),
        Figure("demo", (Chart(pick("resolution"), "scene", series="{system}", kind="bar"),)),
    ),
)


def _demo_app() -> typer.Typer:
    demo = typer.Typer()
    register(demo, DEMO)
    register(demo, Bench("other", DemoConfig, _demo_measure, help="Typer needs two commands for subcommand names."))
    return demo


def _options(typer_app: typer.Typer, name: str) -> dict:
    command = typer.main.get_command(typer_app).commands[name]  # type: ignore[attr-defined]
    return {opt: p for p in command.params for opt in p.opts}


def test_runner_builds_typed_documented_options_from_the_config(tmp_path: Path) -> None:
    opts = _options(_demo_app(), "demo")
    assert {
        "--scenes",
        "--resolution",
        "--tau",
        "--denoise",
        "--warp",
        "--cost-ms",
        "--models",
        "--frames",
        "--out",
        "--quick",
        "--seed",
    } <= set(opts)
    assert opts["--denoise"].secondary_opts == ["--no-denoise"]
    args = ["demo", "--quick", "--resolution", "24", "--tau", "0.5", "--denoise", "--warp", "pixel", "--cost-ms", "2.5"]
    args += ["--models", "x=y.onnx", "--frames", "0,7", "--seed", "4", "--out", str(tmp_path)]
    result = CliRunner().invoke(_demo_app(), args)
    assert result.exit_code == 0, result.output
    settings = json.loads((tmp_path / "demo.provenance.json").read_text())["settings"]
    assert settings == {
        "scenes": ["lung_plane"],
        "resolution": 24,
        "tau": 0.5,
        "denoise": True,
        "warp": "pixel",
        "cost_ms": 2.5,
        "models": {"x": "y.onnx"},
        "frames": [0, 7],
    }
    for bad in (["--resolution", "2.5"], ["--tau", "x"], ["--warp", "diagonal"]):  # typed options: usage errors
        assert CliRunner().invoke(_demo_app(), ["demo", *bad, "--out", str(tmp_path)]).exit_code == 2, bad
    help_text = CliRunner(env={"COLUMNS": "250"}).invoke(_demo_app(), ["demo", "--help"]).output
    assert "Square resolution in pixels. (default: 64; --quick: 16)" in help_text
    assert "Frame indices (0 allowed). (default: 0,5)" in help_text


def test_field_docs_come_from_comments_or_metadata() -> None:
    @dataclass(frozen=True)
    class C:
        #: Documented
        #: over two lines.
        a: int = 1
        b: int = field(default=2, metadata={"help": "from metadata"})

    assert field_docs(C) == {"a": "Documented over two lines.", "b": "from metadata"}
    with pytest.raises(TypeError, match="C.b has no #: comment"):
        undocumented = dataclasses.make_dataclass(
            "C", [("b", int, 2)], frozen=True, namespace={"quick": classmethod(lambda cls: cls())}
        )
        register(typer.Typer(), Bench("c", undocumented, _demo_measure, help=""))


def test_quick_preset_then_only_the_options_given() -> None:
    cfg = build_config(
        DemoConfig, True, {"scenes": "lung_plane, vessels_plane", "models": "x=1.onnx,y=2.onnx", "frames": "0,3"}
    )
    assert cfg.scenes == ("lung_plane", "vessels_plane") and cfg.frames == (0, 3)
    assert cfg.models == {"x": Path("1.onnx"), "y": Path("2.onnx")}
    assert (cfg.resolution, cfg.denoise) == (16, False)  # absent options keep the preset's values
    assert build_config(DemoConfig, False, {"resolution": 32}) == DemoConfig(resolution=32)
    assert build_config(DemoConfig, True, {"denoise": True}).denoise is True  # an explicit flag beats the preset
    assert build_config(DemoConfig, False, {"tau": 0.0}).tau == 0.0  # zero where the field allows it


@pytest.mark.parametrize(
    ("given", "message"),
    [
        ({"resolution": 0}, "--resolution = 0 is below 8"),  # a resolution's limits, by its name
        ({"resolution": -3}, "--resolution = -3 is below 8"),
        ({"resolution": 4096}, "--resolution = 4096 is above 2048"),
        ({"cost_ms": 0.0}, "--cost-ms = 0.0 is not positive"),
        ({"cost_ms": float("nan")}, "--cost-ms = nan is not finite"),
        ({"tau": -0.1}, "--tau = -0.1 is below 0.0"),
        ({"tau": 2.0}, "--tau = 2.0 is above 1.0"),
        ({"frames": "0,-1"}, "--frames = -1 is below 0"),
        ({"frames": "1,x"}, "--frames 'x' is not a valid int"),
        ({"scenes": " , "}, "--scenes is empty"),
        ({"scenes": "lung_plane,no_such_scene"}, "--scenes 'no_such_scene'"),
        ({"models": "a.onnx"}, "--models 'a.onnx' is not a list of NAME=VALUE pairs"),
    ],
)
def test_bad_values_are_user_errors_naming_the_option(given: dict, message: str) -> None:
    with pytest.raises(UserError, match="^" + message.replace("(", r"\(").replace(".", r"\.")):
        build_config(DemoConfig, False, given)


def test_execute_writes_csv_provenance_of_the_final_config_tables_and_figures(tmp_path: Path) -> None:
    cfg = build_config(DemoConfig, True, {"resolution": 24})
    paths = execute(DEMO, cfg, tmp_path, seed=5)
    assert [p.name for p in paths] == ["demo.csv", "demo.provenance.json", "note.md", "demo.md", "demo.png", "demo.svg"]
    assert "| lung_plane | 24 |" in (tmp_path / "demo.md").read_text()
    prov = json.loads((tmp_path / "demo.provenance.json").read_text())
    assert prov["settings"]["resolution"] == 24 and prov["settings"]["denoise"] is False and prov["seed"] == 5
    assert prov["settings"]["models"] == {"a": "a.onnx"} and prov["files"] == [str(tmp_path / "note.md")]
    assert read_rows(tmp_path / "demo.csv")[0]["value"] == 24.0


def _bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=REPO, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    ("args", "culprit"),
    [
        (["warp", "--resolution", "0"], "--resolution = 0 is below 8"),
        (["fov", "--gi-fovs", "90,180"], "--gi-fovs = 180.0 is above 179.0"),
        (["frequency", "--tau", "1.5"], "--tau = 1.5 is above 1.0"),
        (["run-default", "--scenes", "lung_plane,lung_cornell"], "--scenes has 2 values"),
        (["quality", "--models", "gigan=missing.onnx"], "--models gigan missing.onnx: no such model file"),
        (["quality", "--datasets", "tests"], "--datasets tests: no dataset of"),
        (["training"], "--runs is empty"),
        (["training", "--runs", "tests"], "--runs tests: tests/metrics.csv is missing"),
        (["model-card"], "--run is not given"),
        (["render", "--resolution", "-5"], "--resolution = -5 is below 8"),
        (["convergence", "--spps", "1,0"], "--spps = 0 is not positive"),
        (["convergence", "--scenes", ""], "--scenes is empty"),
        (["render", "--resolution", "abc"], "--resolution"),
        (["render", "--out", "README.md"], "--out README.md is a file"),
        (["web", "--model", "missing.onnx"], "--model missing.onnx is not a file"),
        (["web", "--model", "README.md"], "model.json is missing"),
    ],
)
def test_bench_command_rejects_bad_input_with_one_error_line(args: list[str], culprit: str) -> None:
    result = _bench(*args)
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and culprit in errors[0], result.stderr
    assert "Traceback" not in result.stderr + result.stdout


def test_every_subcommand_has_out_quick_and_seed() -> None:
    group = typer.main.get_command(app)
    assert set(group.commands) >= {
        "convergence",
        "render",
        "warp",
        "frequency",
        "fov",
        "quality",
        "training",
        "model-card",
        "run-default",
        "storage",
    }  # type: ignore[attr-defined]
    for name in group.commands:  # type: ignore[attr-defined]
        assert {"--out", "--quick", "--seed"} <= set(_options(app, name)), name


def test_tiny_render_run_through_the_command(tmp_path: Path) -> None:
    result = _bench(
        "render", "--quick", "--resolution", "16", "--repeats", "1", "--gt-repeats", "1", "--gl-resolutions", "16",
        "--gl-repeats", "1", "--out", str(tmp_path),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    written = ["render.csv", "render.provenance.json", "render.md", "render.png", "render.svg"]
    assert result.stdout.split() == [word for name in written for word in ("wrote", str(tmp_path / name))]
    rows = read_rows(tmp_path / "render.csv")
    assert {r["metric"] for r in rows} >= {"triangles", "di_1spp", "gt_256spp"}
    assert any(r["config"].get("pass_set") == "client" for r in rows)
    prov = json.loads((tmp_path / "render.provenance.json").read_text())
    assert {"scenes": ["lung_plane"], "resolution": 16, "repeats": 1, "gt_repeats": 1}.items() <= prov[
        "settings"
    ].items()
    assert (tmp_path / "render.png").stat().st_size > 10_000
    assert ">gt_256spp</text>" in (tmp_path / "render.svg").read_text()  # each pass a series of bars


def test_results_are_tidy_with_provenance(tmp_path: Path) -> None:
    res = Results("demo", tmp_path, seed=3, settings={"k": 1})
    res.add(system="a", scene="s", metric="ssim", value=0.5, unit="1", spp=4)
    res.add_timing(system="a", scene="s", metric="t", samples_s=[0.001, 0.002, 0.003])
    rows = read_rows(res.write())
    assert list(rows[0]) == list(COLUMNS)
    assert rows[0]["config"] == {"spp": 4} and rows[0]["value"] == 0.5
    assert {(r["stat"], r["value"]) for r in rows if r["metric"] == "t"} >= {("median", 2.0), ("n", 3.0)}
    prov = json.loads((tmp_path / "demo.provenance.json").read_text())
    assert (
        prov["seed"] == 3 and prov["rows"] == 4 and {"sha", "dirty"} <= set(prov["git"]) and prov["versions"]["numpy"]
    )


def test_timing_warms_up_and_summarises() -> None:
    calls = []
    samples, result = time_repeats(lambda: calls.append(1) or len(calls), repeats=3, warmup=2)
    assert len(samples) == 3 and len(calls) == 5 and result == 5
    assert summarize_ms([0.001, 0.003])["median"] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="repeats"):
        time_repeats(lambda: None, repeats=0)


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


def test_training_minutes_sum_the_logged_step_times() -> None:
    from bench.common import training_minutes

    # 10 steps at 6 s, then 20 at 3 s; step 40 extrapolates at the last rate.
    assert training_minutes([(10, 6.0), (30, 3.0)], [0, 5, 10, 30, 40]) == pytest.approx([0, 0.5, 1.0, 2.0, 2.5])


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
def test_quick_runs_work_on_a_fresh_checkout(tmp_path: Path) -> None:
    """No data, no runs: --quick renders the small dataset, trains, exports and scores what it needs (~1 min)."""
    out = tmp_path / "out"
    result = _bench("training", "--quick", "--train-steps", "6", "--widths", "4", "--out", str(out))
    assert result.returncode == 0, result.stderr
    steps = {
        r["config"]["step"]
        for r in read_rows(out / "training.csv")
        if r["system"] == "gigan_ngf4" and r["metric"] == "val_ssim"
    }
    assert max(steps) == 6 and (out / "dataset" / "lung_plane" / "meta.json").is_file()

    result = _bench("quality", "--quick", "--scenes", "lung_plane", "--timing-repeats", "1", "--out", str(out))
    assert result.returncode == 0, result.stderr
    ssim = {r["system"]: r["value"] for r in read_rows(out / "quality.csv") if r["metric"] == "ssim"}
    assert ssim["gigan"] > ssim["di_only"]  # the shipped model adds GI that DI lacks, on the rendered held-out frames
    lf = {r["system"]: r["value"] for r in read_rows(out / "quality.csv") if r["metric"] == "lf_error"}
    assert set(lf) == {"gigan", "di_only"} and all(0 < v < 0.1 for v in lf.values())
    assert {"quality_grid.png", "quality.png", "quality_pareto.png"} <= {p.name for p in out.iterdir()}

    result = _bench(
        "model-card", "--quick", "--train-steps", "6", "--width", "4", "--out", str(out)
    )  # resumes the run above
    assert result.returncode == 0, result.stderr
    card = (out / "export" / "gigan_ngf4" / "MODEL_CARD.md").read_text()
    assert "Stopped at optimizer step 6" in card and "| lung_plane |" in card and "| LF error |" in card
    assert {r["metric"] for r in read_rows(out / "model-card.csv")} >= {
        "training_steps",
        "val_ssim",
        "ssim",
        "file_size",
    }
    assert (out / "model_card.png").is_file() and (out / "quality" / "quality.csv").is_file()


@pytest.mark.slow
def test_run_default_is_the_make_run_job(tmp_path: Path) -> None:
    """bench latency --quick --renderers gl and bench storage --quick on lung_plane with the shipped model, both
    tables printed once, at the end; the clients fly 30 frames instead of 90 (the same path, a third of the maps)."""
    argv = [sys.executable, "-m", "bench", "run-default", "--frames", "30", "--out", str(tmp_path)]
    result = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=1200)
    assert result.returncode == 0, result.stderr
    names = {p.name for p in tmp_path.iterdir()}
    assert {
        "latency.csv",
        "latency.md",
        "latency_stages.png",
        "storage.csv",
        "storage.md",
        "run-default.csv",
    } <= names
    assert json.loads((tmp_path / "latency.provenance.json").read_text())["settings"]["frames"] == 30
    assert {r["system"] for r in read_rows(tmp_path / "run-default.csv") if r["metric"] == "wall_time"} == {
        "latency",
        "storage",
    }
    totals = {
        (r["system"], r["config"]["profile"], r["config"].get("cache"))
        for r in read_rows(tmp_path / "latency.csv")
        if r["metric"] == "total"
    }
    assert totals >= {("gigan", "none", None)} | {
        ("cloud_baking", p, c) for p in ("lan", "wan") for c in ("hit", "miss")
    }
    # the clients rasterise with GL (mitsuba after one warning where no GL context opens), and say which ran
    from gicore.gl import gl_available

    renderers = json.loads((tmp_path / "latency.provenance.json").read_text())["settings"]["renderers"]
    assert renderers["asked"] == ["gl"] and len(renderers["ran"]) == 1
    ran = {r["config"]["renderer"] for r in read_rows(tmp_path / "latency.csv") if r["metric"] == "total"}
    assert ran == set(renderers["ran"]) == ({"gl"} if gl_available()[0] else {"mitsuba"})
    assert {r["scene"] for r in read_rows(tmp_path / "storage.csv") if r["scene"] != "all"} == {"lung_plane"}
    assert result.stdout.count("## Table 1") == 1 and result.stdout.count("# Table 2") == 1


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
