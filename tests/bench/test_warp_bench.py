"""``bench warp --renderer gl|mitsuba``: the warps' local passes (structure-aware's uv pass, pixel-level's
surface-mask pass) and the DI from OpenGL or Mitsuba, on the same path-traced GI maps; a tiny user-mesh scene at
32² (seconds)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import warp_bench
from bench.runner import execute
from gicore.error_policy import UserError
from gicore.options import build_config
from gicore.results import read_rows

#: Largest |GL − Mitsuba| of a warp's mean SSIM and valid fraction on the same GI maps: the local passes sample the
#: same pixel centres of the same triangles, so the warps agree (measured here: SSIM 2e-4 structure-aware, 4e-3
#: pixel-level; valid fractions equal).
SSIM_GAP = 0.02
VALID_GAP = 0.01


def tiny(spec_file: Path, renderer: str) -> warp_bench.WarpBenchConfig:
    return warp_bench.WarpBenchConfig(
        scenes=(str(spec_file),),
        resolution=32,
        gi_frames=(0,),
        offsets=(1, 5),
        spp=4,
        denoise=False,
        repeats=1,
        warmup=0,
        renderer=renderer,
    )


@pytest.fixture(scope="module")
def spec_file(make_spec, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("warp_spec") / "ball.json"
    path.write_text(json.dumps(make_spec(with_box=True).to_dict()))
    return path


def summary(out: Path) -> dict[tuple[str, str, str], dict]:
    return {(r["system"], r["metric"], r["stat"]): r for r in read_rows(out / "warp.csv")}


def test_gl_passes_warp_as_mitsuba_passes_do(spec_file: Path, tmp_path: Path) -> None:
    from gicore.gl import gl_available

    if not gl_available()[0]:
        pytest.skip(f"no OpenGL context: {gl_available()[1]}")
    runs = {}
    for renderer in ("gl", "mitsuba"):
        execute(warp_bench.BENCH, tiny(spec_file, renderer), tmp_path / renderer)
        runs[renderer] = summary(tmp_path / renderer)
    gl, mi = runs["gl"], runs["mitsuba"]
    assert {r["config"]["renderer"] for r in gl.values()} == {"gl"}
    assert {r["config"]["renderer"] for r in mi.values()} == {"mitsuba"}
    assert gl["structure-aware", "ssim", "mean"]["config"]["gl_lod"] == "auto"
    for run in (gl, mi):  # the DI alone beside the methods' DI + pass
        di_alone = run["DI alone", "raster_time", "median"]["value"], run["DI alone", "raster_time", "n"]["value"]
        assert di_alone[0] > 0 and di_alone[1] == 2
    for system in warp_bench.SYSTEMS.values():  # each method's own local pass is timed, on either renderer
        for run in (gl, mi):
            assert run[system, "raster_time", "median"]["value"] > 0 and run[system, "raster_time", "n"]["value"] == 2
        for metric, gap in (("ssim", SSIM_GAP), ("valid_fraction", VALID_GAP)):
            a, b = gl[system, metric, "mean"]["value"], mi[system, metric, "mean"]["value"]
            assert abs(a - b) <= gap, (system, metric, a, b)
    # The GL vertex shader's projection (eq. 5 in homogeneous clip coordinates) lands where per-pixel
    # projection of GL's own position pass does, as Mitsuba's uploaded coordinates do.
    for run in (gl, mi):
        assert run["homogeneous clip (ours)", "uv_error", "max"]["value"] < 0.01


def test_gl_without_a_context_runs_mitsuba_and_says_so(
    spec_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    import gicore.gl.context as context

    monkeypatch.setattr(context, "_context", None)
    monkeypatch.setattr(context, "_failure", "no EGL display here")
    execute(warp_bench.BENCH, tiny(spec_file, "gl"), tmp_path)
    assert {r["config"]["renderer"] for r in read_rows(tmp_path / "warp.csv")} == {"mitsuba"}
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings == ["warning: renderer gl is unavailable, using mitsuba: no EGL display here"]


def test_renderer_options_are_checked() -> None:
    cfg = build_config(warp_bench.WarpBenchConfig, {"renderer": "mitsuba", "gl_lod": "2"})
    assert (cfg.renderer, cfg.gl_lod) == ("mitsuba", "2")
    assert warp_bench.WarpBenchConfig().renderer == "gl"  # the clients' default
    with pytest.raises(UserError, match="--renderer 'vulkan' is not one of gl, mitsuba"):
        build_config(warp_bench.WarpBenchConfig, {"renderer": "vulkan"})
    with pytest.raises(UserError, match="--gl-lod 'coarse' is not one of"):
        build_config(warp_bench.WarpBenchConfig, {"gl_lod": "coarse"})
