"""The bench framework: the runner (options from configs, presets, checks, --out), tidy CSV + provenance, and
the ``bench`` command's subcommands and its one-line errors (tiny real bench runs: tests/bench/test_tiny_runs.py)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest
import typer
from typer.testing import CliRunner

from bench.cli import app
from bench.runner import Bench, build_config, execute, field_docs, register
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.present.declarations import Chart, Column, Figure, Table, pick
from gicore.results import COLUMNS, Results, read_rows
from gicore.timing import summarize_ms, time_repeats
from tests.helpers.cli import assert_user_error, exit_status

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


@pytest.mark.parametrize(
    ("args", "culprit"),
    [
        (["warp", "--resolution", "0"], "--resolution = 0 is below 8"),
        (["fov", "--gi-fovs", "90,180"], "--gi-fovs = 180.0 is above 179.0"),
        (["frequency", "--tau", "1.5"], "--tau = 1.5 is above 1.0"),
        (["run-default", "--scenes", "lung_plane,lung_cornell"], "--scenes has 2 values"),
        (["quality", "--models", "gigan=missing.onnx"], "--models gigan missing.onnx is not a file"),
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
def test_bench_command_rejects_bad_input_with_one_error_line(
    args: list[str], culprit: str, capsys: pytest.CaptureFixture
) -> None:
    assert exit_status(["bench", *args], REPO) == 2
    out, err = capsys.readouterr()
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and culprit in errors[0], err
    assert "Traceback" not in err + out


def test_the_installed_bench_script_rejects_bad_input_in_one_line(tmp_path: Path) -> None:
    """The console script as a process (the cases above run its main here): exit 2, one line, nothing written."""
    (tmp_path / "a_file").write_text("")
    assert_user_error(["bench", "render", "--out", "a_file"], "--out a_file is a file", cwd=tmp_path)


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
