"""The low-frequency error in the quality tables: ``bench quality`` (rows, bars, error-map grid),
``bench model-card`` and the report's quality section, on a synthetic dataset whose GT is its DI made
brighter by a known amount, scored with a real ONNX pass-through "generator" (no rendering: seconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bench import model_card, quality
from bench.quality_grid import grid_rows, lf_colours
from bench.runner import execute
from gicore.dataset import DatasetMeta, FrameRecord, load_frame, read_meta, save_frame, write_meta
from gicore.dataset_cli import inputs_renderer
from gicore.error_policy import UserError
from gicore.metrics import lf_error
from gicore.present.declarations import shown
from gicore.present.html import parts_html
from gicore.present.markdown import table_text, tables_text
from gicore.results import Results, read_rows
from gicore.run_config import CLIENT_LOD
from gicore.tonemap import inverse_tonemap, tonemap
from tests.helpers.cloud import passthrough_model
from tests.helpers.model_card import write_run_and_export

RES = 64
OFFSET = 0.05  # the GT is the DI brighter by this much, tone-mapped
N_FRAMES = 2


def write_dataset(root: Path) -> None:
    """``N_FRAMES`` val frames: DI a smooth ramp with a bright square, GT = DI + OFFSET (tone-mapped)."""
    rng = np.random.default_rng(3)
    buffers = ["di", "albedo", "normal", "depth", "gt"]
    records = []
    y, x = np.mgrid[0:RES, 0:RES] / RES
    for i in range(N_FRAMES):
        di_tm = np.clip(0.2 + 0.4 * x + 0.1 * y + 0.2 * ((x > 0.5) & (y > 0.5)), 0.0, 0.9)[..., None] * np.array(
            [1.0, 0.9, 0.8]
        )
        di_tm = di_tm + rng.uniform(0.0, 0.02, di_tm.shape)
        frame = {
            "di": inverse_tonemap(di_tm),
            "gt": inverse_tonemap(di_tm + OFFSET),
            "albedo": np.full((RES, RES, 3), 0.7),
            "normal": np.dstack([np.zeros((RES, RES)), np.ones((RES, RES)), np.zeros((RES, RES))]),
            "depth": np.full((RES, RES, 1), 3.0),
        }
        save_frame(root / "val" / f"{i:06d}.npz", frame)
        eye = np.eye(4).tolist()
        records.append(FrameRecord(split="val", index=i, camera={}, view=eye, proj=eye))
    write_meta(
        root,
        DatasetMeta(
            scene={"name": "synthetic"}, resolution=RES, spp=1, denoise=False, seed=0, buffers=buffers, frames=records
        ),
    )


@pytest.fixture(scope="module")
def scored(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(bench quality output folder, data root) for the synthetic scene scored with DI alone and the pass-through."""
    tmp = tmp_path_factory.mktemp("quality_lf")
    write_dataset(tmp / "data" / "synthetic")
    model = passthrough_model(tmp / "model", RES)
    cfg = quality.QualityConfig(
        datasets=tmp / "data", scenes=("synthetic",), models={"copy": model}, timing_repeats=1, grid_frames=1
    )
    execute(quality.BENCH, cfg, tmp / "out")
    return tmp / "out", tmp / "data" / "synthetic"


def test_quality_rows_carry_the_low_frequency_error(scored: tuple[Path, Path]) -> None:
    out, data = scored
    rows = read_rows(out / "quality.csv")
    lf = {r["system"]: r for r in rows if r["metric"] == "lf_error"}
    assert set(lf) == {"di_only", "copy"} and all(r["unit"] == "1" and r["stat"] == "mean" for r in lf.values())
    # The value is the mean of the per-frame lf_error of the stored (float16) frames: about the offset.
    frames = [load_frame(p) for p in sorted((data / "val").glob("*.npz"))]
    expected = float(np.mean([lf_error(tonemap(f["di"]), tonemap(f["gt"])) for f in frames]))
    assert lf["di_only"]["value"] == pytest.approx(expected, abs=1e-9)
    assert expected == pytest.approx(OFFSET, abs=2e-3)
    assert lf["copy"]["value"] == pytest.approx(expected, abs=1e-4)  # the pass-through returns the DI
    # Every metric the table had before is still there, beside the new ones, for both systems.
    assert {(r["system"], r["metric"]) for r in rows if r["stat"] == "mean"} == {
        (s, m)
        for s in ("di_only", "copy")
        for m in ("rmse", "ssim", "psnr", "lf_error", "checker_error", "shadow_tint")
    }
    # A uniform offset is neither a checkerboard nor (grey) a tint.
    for metric in ("checker_error", "shadow_tint"):
        assert all(abs(r["value"]) < 1e-3 for r in rows if r["metric"] == metric)
    assert {"quality.png", "quality.svg", "quality_pareto.png", "quality_grid.png"} <= {p.name for p in out.iterdir()}
    bars = (out / "quality.svg").read_text()
    assert all(f">{name}</text>" in bars for name in ("di_only", "copy"))  # each system's bars, in the legend


def test_quality_grid_shows_the_error_maps_on_the_fixed_scale(scored: tuple[Path, Path]) -> None:
    """Columns DI | albedo | normal | copy | GT; per frame rows: images, |error|, low-frequency error."""
    out, _ = scored
    grid = np.asarray(Image.open(out / "quality_grid.png").convert("RGB")).astype(float) / 255.0
    header = 16
    assert grid.shape[1] == 5 * RES and grid.shape[0] > header + 3 * RES
    y_abs, y_lf = header + RES + RES - 4, header + 2 * RES + RES - 4  # near each cell's bottom, below its text
    for col in (0, 3):  # DI alone's and the pass-through's error maps
        x = col * RES + RES // 2
        # |error| x4 of a 0.05 offset: 0.2 in every channel
        np.testing.assert_allclose(grid[y_abs, x], 4 * OFFSET, atol=0.02)
        # darker than GT by 0.05: half-way to the blue end of the +-0.1 scale
        np.testing.assert_allclose(grid[y_lf, x], lf_colours(np.array(-OFFSET)), atol=0.03)
        assert grid[y_lf, x, 2] > grid[y_lf, x, 0] + 0.2  # blue, not red
    assert np.all(grid[y_lf, 4 * RES + RES // 2] == 1.0)  # nothing under GT


def test_grid_rows_sign_and_layout() -> None:
    ref = np.full((16, 16, 3), 0.5)
    frame = {"albedo": np.full((16, 16, 3), 0.3), "normal": np.zeros((16, 16, 3))}
    rows = grid_rows(frame, {"di_only": ref - 0.1, "a": ref + 0.05, "b": ref}, ref, "t")
    assert [len(r) for r in rows] == [6, 6, 6]
    (lf_di, text_di), (lf_a, text_a), (lf_b, text_b) = rows[2][0], rows[2][3], rows[2][4]
    assert (text_di, text_a, text_b) == ("LF 0.1000", "LF 0.0500", "LF 0.0000")
    np.testing.assert_allclose(lf_di, lf_colours(np.full((16, 16), -0.1)))  # the scale's blue end
    np.testing.assert_allclose(lf_b, lf_colours(np.zeros((16, 16))))  # no error: the scale's middle,
    assert lf_b.min() > 0.95 and np.ptp(lf_b) < 0.01  # near-white grey (RdBu_r's middle is 0.97, 0.97, 0.96)
    assert lf_a[0, 0, 0] > lf_a[0, 0, 2] + 0.2  # brighter than GT: red
    np.testing.assert_allclose(rows[1][3][0], 4 * 0.05)


def test_model_card_and_report_show_the_low_frequency_error(scored: tuple[Path, Path], tmp_path: Path) -> None:
    out, _ = scored
    run, export = tmp_path / "run", tmp_path / "export"
    write_run_and_export(run, export, RES)
    res = Results("model-card", tmp_path / "card")
    cfg = model_card.ModelCardConfig(run=run, export=export, quality_csv=out / "quality.csv", system="copy")
    model_card.measure(cfg, res, quality.BENCH)
    assert res.files == [export / "MODEL_CARD.md"]
    card = res.files[0].read_text()
    lf = {r["system"]: r["value"] for r in read_rows(out / "quality.csv") if r["metric"] == "lf_error"}
    assert "| scene | SSIM | PSNR dB | RMSE | LF error | DI alone SSIM | DI alone LF error |" in card
    row = next(line for line in card.splitlines() if line.startswith("| synthetic |")).split(" | ")
    assert (row[4], row[6]) == (f"{lf['copy']:.4f}", f"{lf['di_only']:.4f}")
    assert "LF error 0.0123." in card
    res_rows = {(r["system"], r["metric"]): r for r in res.rows}
    assert (
        res_rows["export", "lf_error"]["value"] == pytest.approx(lf["copy"])
        and res_rows["export", "val_lf_error"]["unit"] == "1"
    )

    html = parts_html(shown(quality.PARTS, "dashboard"), read_rows(out / "quality.csv"), out)
    assert quality.TITLES["lf_error"] in html and "<th>LF error</th>" in html  # its bars, and its column
    assert f"<td>{lf['copy']:.4g}</td>" in html


# -- the inputs' renderer --------------------------------------------------------------------------------------------
#: The shipped model on GL inputs against Mitsuba inputs, 2 held-out lung_plane frames at 256² (raw 32-spp GT): paired
#: SSIM difference measured +0.0007 (standard error 1.2e-4) and LF error ratio 1.03 here (0.93 with 16 held-out
#: frames and a 64-spp + OIDN GT); the bounds are bench quality's GL rule.
GL_SSIM_DIFF_MIN = -0.005
GL_LF_RATIO_MAX = 1.2


def test_shipped_model_loses_little_on_gl_inputs(tmp_path: Path) -> None:
    """``bench quality --renderers gl,mitsuba`` on a small held-out lung_plane dataset (Mitsuba inputs and GT): the
    gl rows are the model on inputs GLRenderer(lod="auto") renders now at the same frames, scored against the same
    GT, and the paired SSIM difference and LF ratio stay within the GL rule."""
    from gicore.dataset_cli import DatasetConfig
    from gicore.gl import gl_available
    from gigan_local.inference import DEFAULT_MODEL

    if not gl_available()[0]:
        pytest.skip(f"no OpenGL context: {gl_available()[1]}")
    from gicore.dataset_cli import build_dataset
    from gicore.scene import load_scene

    cfg_ds = DatasetConfig(n_train=0, n_val=2, resolution=256, spp=32, denoise=False)  # OIDN's load: seconds
    build_dataset(load_scene("lung_plane"), tmp_path / "data" / "lung_plane", cfg_ds, progress=False)
    cfg = quality.QualityConfig(
        datasets=tmp_path / "data",
        scenes=("lung_plane",),
        models={"gigan": DEFAULT_MODEL},
        timing_repeats=1,
        grid_frames=0,
        renderers=("gl", "mitsuba"),
    )
    cfg.check()
    res = Results("quality", tmp_path / "out")
    quality.measure(cfg, res)  # the bench without its plots (seconds of matplotlib)
    rows = read_rows(res.write())
    mean = {(r["system"], r["config"]["renderer"], r["metric"]): r for r in rows if r["stat"] == "mean"}
    for renderer in ("gl", "mitsuba"):  # the model adds GI on either renderer's inputs
        assert mean["gigan", renderer, "ssim"]["value"] > mean["di_only", renderer, "ssim"]["value"] + 0.03
    gl_row = mean["gigan", "gl", "ssim"]["config"]
    assert (
        gl_row["gl_lod"] == "auto"
        and 0 <= gl_row["gl_level_mean"] <= 5
        and "gl_lod" not in mean["gigan", "mitsuba", "ssim"]["config"]
    )
    diff = mean["gigan", "gl", "ssim_diff"]["value"]
    assert diff == pytest.approx(mean["gigan", "gl", "ssim"]["value"] - mean["gigan", "mitsuba", "ssim"]["value"])
    ratio = next(r["value"] for r in rows if r["metric"] == "lf_error_ratio" and r["system"] == "gigan")
    assert ratio == pytest.approx(
        mean["gigan", "gl", "lf_error"]["value"] / mean["gigan", "mitsuba", "lf_error"]["value"]
    )
    assert GL_SSIM_DIFF_MIN <= diff and ratio <= GL_LF_RATIO_MAX, (diff, ratio)
    table = tables_text(quality.PARTS, rows, 2)
    assert "| gigan (gl) | lung_plane |" in table and "| gigan | lung_plane | gl | " in table and "| yes |" in table


def test_renderer_table_applies_the_rule() -> None:
    def row(system: str, metric: str, value: float, stat: str, renderer: str = "gl") -> dict:
        return {
            "system": system,
            "scene": "s",
            "metric": metric,
            "stat": stat,
            "value": value,
            "config": {"renderer": renderer},
        }

    rows = [row("ok", "ssim_diff", -0.004, "mean"), row("ok", "lf_error_ratio", 1.19, "ratio")]
    rows += [row("ssim", "ssim_diff", -0.006, "mean"), row("ssim", "lf_error_ratio", 1.0, "ratio")]
    rows += [row("lf", "ssim_diff", 0.001, "mean"), row("lf", "lf_error_ratio", 1.21, "ratio")]
    verdict = {
        line.split(" | ")[0][2:]: line.rstrip(" |").rsplit("| ", 1)[1]
        for line in table_text(quality.RENDERERS, rows, 2).splitlines()[2:]
    }
    assert verdict == {"ok": "yes", "ssim": "**no**", "lf": "**no**"}
    assert table_text(quality.RENDERERS, [row("a", "ssim", 0.9, "mean")], 2) == ""


def test_renderers_option_is_checked(scored: tuple[Path, Path], tmp_path: Path, monkeypatch) -> None:
    from gicore.options import build_config

    _, data = scored
    assert build_config(quality.QualityConfig, {"renderers": "gl,mitsuba"}).renderers == ("gl", "mitsuba")
    with pytest.raises(UserError, match="--renderers 'vulkan' is not one of gl, mitsuba"):
        build_config(quality.QualityConfig, {"renderers": "vulkan"})
    with pytest.raises(UserError, match="--renderers mitsuba,mitsuba is not a list of distinct renderers"):
        quality.QualityConfig(renderers=("mitsuba", "mitsuba")).check()
    # No GL context here: refused before anything is measured, with the reason.
    import gicore.gl.context as context

    monkeypatch.setattr(context, "_context", None)
    monkeypatch.setattr(context, "_failure", "no EGL display here")
    with pytest.raises(UserError, match="--renderers gl: no EGL display here"):
        quality.QualityConfig(renderers=("gl",)).check()
    monkeypatch.undo()
    # A dataset whose scene spec does not load cannot be rendered again by another renderer: one clear error.
    with pytest.raises(UserError, match="its scene spec does not load to render gl's"):
        inputs_renderer(read_meta(data), data, "gl", CLIENT_LOD, "--renderers")
