"""The model card: what it states from a run folder, an export folder and quality rows, and the rows it refuses."""

from __future__ import annotations

from pathlib import Path

import pytest

from gicore.error_policy import UserError
from gigan_local.model_card import CARD_NAME, ModelCard, TrainingRun, training_minutes
from tests.helpers.model_card import write_run_and_export

SOURCE = Path("somewhere/quality.csv")


def quality_rows(renderer: str = "mitsuba", lf_error: bool = True) -> list[dict]:
    """A quality CSV's rows (as ``gicore.results.read_rows`` gives them) for one scene: the model ``copy``
    and DI alone, scored on ``renderer``'s inputs."""
    means = {"copy": {"ssim": 0.9, "psnr": 25.0, "rmse": 0.05}, "di_only": {"ssim": 0.8}}
    if lf_error:
        means["copy"]["lf_error"], means["di_only"]["lf_error"] = 0.04, 0.05
    base = {"scene": "synthetic", "unit": "1", "run_id": "q1", "config": {"renderer": renderer}}
    rows = [
        base | {"system": s, "metric": m, "stat": "mean", "value": v} for s, ms in means.items() for m, v in ms.items()
    ]
    return rows + [base | {"system": "copy", "metric": "inference_time", "stat": "median", "value": 3.21}]


@pytest.fixture
def folders(tmp_path: Path) -> tuple[Path, Path]:
    run, export = tmp_path / "run", tmp_path / "export"
    write_run_and_export(run, export, 64)
    return run, export


def test_the_card_states_the_run_the_export_and_the_quality_rows(folders: tuple[Path, Path]) -> None:
    run, export = folders
    card = ModelCard.read(run, export, quality_rows(), "copy", SOURCE)
    assert (card.training.last_step, card.training.val["lf_error"], card.sizes) == (4, 0.0123, {"fp32": 1 / 1024})
    path = card.write("render it", "train it")
    assert path == export / CARD_NAME
    text = path.read_text()
    assert text.startswith("# Model card: export\n")
    assert "(U-Net, ngf 8, 6 down-samplings, 4x4 stride-2 transposed-conv up-sampling)" in text
    assert "`render it`" in text and "`train it`" in text
    assert "Stopped at optimizer step 4 (epoch 1); median step time 0.5 s on this machine's CPU" in text
    assert "0.0333 min of steps in all" in text  # 4 steps of 0.5 s
    assert "SSIM 0.9000, PSNR 25.00 dB, RMSE 0.0500, LF error 0.0123." in text
    assert "| synthetic | 0.9000 | 25.00 | 0.0500 | 0.0400 | 0.8000 | 0.0500 | 3.2 |" in text
    assert "n/a" not in text
    assert "- `model.onnx`: fp32 weights, 0.00 MiB, max |onnxruntime − torch| = 1.00e-06" in text
    assert text.endswith("Metrics source: `quality.csv` (run q1).\n")


def test_a_card_marks_metrics_its_quality_rows_predate(folders: tuple[Path, Path]) -> None:
    text = "\n".join(ModelCard.read(*folders, quality_rows(lf_error=False), "copy", SOURCE).lines("d", "t"))
    assert "n/a: the quality CSV predates it." in text
    assert "| synthetic | 0.9000 | 25.00 | 0.0500 | n/a | 0.8000 | n/a | 3.2 |" in text


def test_a_card_refuses_rows_without_the_model_or_scored_on_two_renderers(folders: tuple[Path, Path]) -> None:
    with pytest.raises(UserError, match="has no rows of system 'gigan'"):
        ModelCard.read(*folders, quality_rows(), "gigan", SOURCE)
    mixed = quality_rows() + quality_rows("gl")
    with pytest.raises(UserError, match="scores 'copy' on the inputs of renderers gl, mitsuba"):
        ModelCard.read(*folders, mixed, "copy", SOURCE)


def test_training_minutes_sum_the_logged_step_times() -> None:
    # 10 steps at 6 s, then 20 at 3 s; step 40 extrapolates at the last rate.
    assert training_minutes([(10, 6.0), (30, 3.0)], [0, 5, 10, 30, 40]) == pytest.approx([0, 0.5, 1.0, 2.0, 2.5])


def test_a_run_folder_reads_as_its_config_and_metrics_rows_and_no_rows_is_told_apart(
    folders: tuple[Path, Path],
) -> None:
    run, _ = folders
    train, metrics = TrainingRun.files(run)
    assert train["n_critic"] == 5 and {r["metric"] for r in metrics} >= {"step_seconds"}
    header = (run / "metrics.csv").read_text().splitlines()[0]
    (run / "metrics.csv").write_text(header + "\n")  # a run stopped before its first log
    assert TrainingRun.files(run) == (train, [])
    with pytest.raises(UserError, match="has no rows: the run stopped before its first log"):
        TrainingRun.read(run)
