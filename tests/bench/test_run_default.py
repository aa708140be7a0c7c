"""`bench run-default` (what ``make run`` runs): what the main job itself owns. It starts bench latency and bench
storage from their quick presets with its own options, checks both configs before either runs, records a wall
time per bench and prints both tables once, at the end. Here the two benches' runs are recorded instead of
measured; each runs end to end in its own test (tests/bench/test_latency.py, test_bench_latency_end_to_end;
tests/bench/test_storage.py)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from bench import run_default
from bench.latency import LatencyConfig
from bench.run_default import RunDefaultConfig
from bench.runner import Bench, execute
from bench.storage_config import StorageConfig
from gicore.error_policy import UserError
from gicore.results import Results, read_rows
from tests.helpers.cli import exit_status

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def ran(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> list[tuple[str, Any, str]]:
    """Each bench run-default starts, in order: its name, its final config and what had been printed before it
    ran. A recorded run writes the bench's table and prints it, as a bench run does."""
    runs: list[tuple[str, Any, str]] = []

    def record(bench: Bench, cfg: Any, out: Path, seed: int = 0) -> list[Path]:
        runs.append((bench.name, cfg, capsys.readouterr().out))
        table = out / f"{bench.name}.md"
        table.write_text(f"# {bench.name} table\n")
        print(f"{bench.name}'s own printout of its table")
        return [table]

    monkeypatch.setattr(run_default, "execute", record)
    return runs


@pytest.mark.parametrize(
    ("args", "latency", "storage"),
    [
        ([], {"scenes": ("lung_plane",), "renderers": ("gl",)}, {"scenes": ("lung_plane",)}),  # make run
        (
            ["--scenes", "vessels_plane", "--renderers", "gl,mitsuba", "--frames", "30"],
            {"scenes": ("vessels_plane",), "renderers": ("gl", "mitsuba"), "frames": 30},
            {"scenes": ("vessels_plane",)},
        ),
    ],
)
def test_both_quick_presets_run_with_its_options_and_both_tables_print_once_at_the_end(
    ran: list, capsys: pytest.CaptureFixture, tmp_path: Path, args: list[str], latency: dict, storage: dict
) -> None:
    # the registered command's real configs: their checks (the shipped model, the scene) pass before either runs
    assert exit_status(["bench", "run-default", *args, "--out", str(tmp_path)]) == 0
    assert [(name, cfg) for name, cfg, _ in ran] == [
        ("latency", dataclasses.replace(LatencyConfig.quick(), **latency)),
        ("storage", dataclasses.replace(StorageConfig.quick(), **storage)),
    ]
    assert [printed for *_, printed in ran] == ["", ""]  # nothing shown while the benches run
    out = capsys.readouterr().out
    assert "own printout" not in out
    assert out.split("wrote ")[0].split() == ["#", "latency", "table", "#", "storage", "table"]
    rows = read_rows(tmp_path / "run-default.csv")
    assert [(r["system"], r["scene"], r["metric"], r["unit"]) for r in rows] == [
        (name, latency["scenes"][0], "wall_time", "s") for name in ("latency", "storage")
    ]
    assert all(r["value"] > 0 for r in rows)
    prov = json.loads((tmp_path / "run-default.provenance.json").read_text())
    assert prov["files"] == [str(tmp_path / "latency.md"), str(tmp_path / "storage.md")]


@dataclass(frozen=True)
class FirstConfig:
    """A bench that would run first."""

    scenes: tuple[str, ...] = ("lung_plane",)
    renderers: tuple[str, ...] = ("gl",)
    frames: int = 90

    @classmethod
    def quick(cls) -> FirstConfig:
        return cls()


@dataclass(frozen=True)
class SecondConfig:
    """A bench whose model is missing."""

    scenes: tuple[str, ...] = ("lung_plane",)
    model: Path = Path("missing.onnx")

    @classmethod
    def quick(cls) -> SecondConfig:
        return cls()

    def check(self) -> None:
        if not self.model.is_file():
            raise UserError(f"--model {self.model} is not a file", "give an exported model")


def test_a_missing_model_fails_before_either_bench_runs(tmp_path: Path) -> None:
    measured: list[Any] = []

    def measure(cfg: Any, res: Results) -> None:
        measured.append(cfg)

    job = run_default.bench(
        Bench("first", FirstConfig, measure, help=""), Bench("second", SecondConfig, measure, help="")
    )
    with pytest.raises(UserError, match="^--model missing.onnx is not a file"):
        execute(job, RunDefaultConfig(), tmp_path)
    assert measured == [] and list(tmp_path.iterdir()) == []


def test_make_run_is_bench_run_default_and_its_help_lists_its_options(
    capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "250")  # the help's lines unwrapped
    assert "$(PY) -m bench run-default --out $(OUT)" in (REPO / "Makefile").read_text()
    assert exit_status(["bench", "run-default", "--help"]) == 0
    help_text = capsys.readouterr().out
    assert "(make run)" in help_text and {"--scenes", "--renderers", "--frames", "--out"} <= set(help_text.split())
