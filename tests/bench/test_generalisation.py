"""`bench quality --generalisation`: the held-out cases rendered once at the models' resolution, each model scored on
the object's own pixels beside DI alone, and every target printed as met or MISSED. Real ONNX pass-through
"generators" (their map is the DI), radiance and albedo-demodulated, on tiny frames: the demodulated one must give
the DI back exactly as the radiance one does, so the client's multiply by the albedo is the encoding's inverse."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import quality
from bench.runner import execute
from gicore.error_policy import UserError
from gicore.heldout_cases import cases
from gicore.results import read_rows
from tests.helpers.cloud import passthrough_model

RES = 32


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("generalisation")
    models = {"copy": passthrough_model(tmp / "copy", RES), "shading": passthrough_model(tmp / "shade", RES, 0.05)}
    cfg = quality.QualityConfig(datasets=tmp / "data", models=models, max_frames=2, generalisation=True)
    execute(quality.BENCH, cfg, tmp / "out")
    return tmp


def test_every_case_is_scored_on_its_object_beside_di_alone(checked: Path) -> None:
    rows = read_rows(checked / "out" / "quality.csv")
    names = {c.name for c in cases()}
    for metric in ("object_psnr", "gain_db", "chroma_error", "ssim"):
        got = {(r["system"], r["scene"]) for r in rows if r["metric"] == metric}
        assert got == {(s, n) for s in ("di_only", "copy", "shading") for n in names}, metric
    gain = {(r["system"], r["scene"]): r["value"] for r in rows if r["metric"] == "gain_db"}
    assert all(abs(v) < 0.05 for v in gain.values())  # both pass-throughs give the DI back, demodulated or not
    psnr = [r for r in rows if r["metric"] == "object_psnr"]
    assert all(10.0 < r["value"] < 60.0 and r["config"]["frames"] == 2 for r in psnr)
    assert len(list((checked / "data" / "generalisation" / str(RES)).iterdir())) == len(names)  # kept for reuse


def test_targets_are_printed_met_or_missed(checked: Path) -> None:
    rows = read_rows(checked / "out" / "quality.csv")
    targets = [r for r in rows if r["stat"] == "target_met"]
    assert {r["system"] for r in targets} == {"copy", "shading"}
    assert not any(r["value"] for r in targets if "gain over DI" in r["config"]["target"])  # DI adds nothing
    text = (checked / "out" / "quality.md").read_text()
    assert "| MISSED |" in text and f"of {len(targets)} met." in text and "object PSNR (dB)" in text


def test_models_of_two_resolutions_are_refused(checked: Path) -> None:
    models = {"a": checked / "copy" / "model.onnx", "b": passthrough_model(checked / "other", 64)}
    cfg = quality.QualityConfig(datasets=checked / "data", models=models, generalisation=True)
    with pytest.raises(UserError, match="one resolution"):
        execute(quality.BENCH, cfg, checked / "refused")
