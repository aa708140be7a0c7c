"""The ``--quick`` benches of a fresh checkout, through the ``bench`` command: with no data and no runs they render
the small dataset, train, export and score what they need (bench training, bench quality, bench model-card)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gicore.results import read_rows
from tests.helpers.cli import exit_status


@pytest.mark.slow
def test_quick_runs_work_on_a_fresh_checkout(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """No data, no runs: --quick renders the small dataset, trains, exports and scores what it needs (~1 min)."""
    out = tmp_path / "out"
    code = exit_status(["bench", "training", "--quick", "--train-steps", "6", "--widths", "4", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    steps = {
        r["config"]["step"]
        for r in read_rows(out / "training.csv")
        if r["system"] == "gigan_ngf4" and r["metric"] == "val_ssim"
    }
    assert max(steps) == 6 and (out / "dataset" / "lung_plane" / "meta.json").is_file()

    code = exit_status(
        ["bench", "quality", "--quick", "--scenes", "lung_plane", "--timing-repeats", "1", "--out", str(out)]
    )
    assert code == 0, capsys.readouterr().err
    ssim = {r["system"]: r["value"] for r in read_rows(out / "quality.csv") if r["metric"] == "ssim"}
    assert ssim["gigan"] > ssim["di_only"]  # the shipped model adds GI that DI lacks, on the rendered held-out frames
    lf = {r["system"]: r["value"] for r in read_rows(out / "quality.csv") if r["metric"] == "lf_error"}
    assert set(lf) == {"gigan", "di_only"} and all(0 < v < 0.1 for v in lf.values())
    assert {"quality_grid.png", "quality.png", "quality_pareto.png"} <= {p.name for p in out.iterdir()}

    code = exit_status(
        ["bench", "model-card", "--quick", "--train-steps", "6", "--width", "4", "--out", str(out)]
    )  # resumes the run above
    assert code == 0, capsys.readouterr().err
    card = (out / "export" / "gigan_ngf4" / "MODEL_CARD.md").read_text()
    assert "Stopped at optimizer step 6" in card and "| lung_plane |" in card and "| LF error |" in card
    assert {r["metric"] for r in read_rows(out / "model-card.csv")} >= {
        "training_steps",
        "val_ssim",
        "ssim",
        "file_size",
    }
    assert (out / "model_card.png").is_file() and (out / "quality" / "quality.csv").is_file()
    assert not (out / "quality" / "dataset").exists()  # scored on the datasets it trained on, not rendered twice
