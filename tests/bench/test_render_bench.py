"""`bench render`'s client raster passes: OpenGL (full detail and lod auto) beside Mitsuba in one run, with the
level lod auto drew and its G-buffer error."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.render_bench import CLIENT_PASSES, GL_LODS, RenderBenchConfig, client_table, measure_client_passes
from gicore.results import Results, read_rows


@pytest.mark.slow  # two GL renderers (decimation, lod calibration), Mitsuba's passes: 8 s idle, 45 s at load 10
def test_client_passes_side_by_side(tmp_path: Path) -> None:
    from gicore.gl import gl_available

    ok, why = gl_available()
    if not ok:
        pytest.skip(f"no OpenGL context: {why}")
    res = Results("render", tmp_path, 0)
    measure_client_passes(RenderBenchConfig(scenes=("lung_plane",), gl_resolutions=(32,), gl_repeats=2), res)
    res.write()
    rows = read_rows(res.csv_path)

    def get(system: str, metric: str, stat: str, **config) -> float:
        [v] = [
            r["value"]
            for r in rows
            if (r["system"], r["metric"], r["stat"]) == (system, metric, stat) and r["config"].items() >= config.items()
        ]
        return v

    for stage in CLIENT_PASSES:
        mitsuba = get("mitsuba", stage, "median")
        assert mitsuba > 0 and get("mitsuba", stage, "n") == 2
        for lod in GL_LODS:
            gl = get("gl", stage, "median", lod=lod)
            assert gl > 0 and get("gl/mitsuba", stage, "ratio", lod=lod) == pytest.approx(gl / mitsuba, rel=1e-3)
    for view in ("gi", "local", "local_shown"):
        assert 0 <= get("gl", "lod_level", "mean", view=view) <= get("gl", "lod_level", "max", view=view) <= 5
        for channel in ("normal", "depth", "coverage"):
            mean, top = (get("gl", f"lod_error_{channel}", stat, view=view) for stat in ("mean", "max"))
            assert 0 <= mean <= top < 0.05  # within the auto bound's order (3e-3 normal), not a broken render
    # the wide GI camera sees the lungs smaller than the local camera, so it may draw a coarser level
    assert get("gl", "lod_level", "mean", view="gi") >= get("gl", "lod_level", "mean", view="local")
    # the shown passes' looser bound never draws a finer level than the model-input bound at the same views
    assert get("gl", "lod_level", "mean", view="local_shown") >= get("gl", "lod_level", "mean", view="local")
    text = client_table(rows)
    assert "### lung_plane, 32²" in text and text.count("| gi_camera |") == 1 and "lod auto at the gi views" in text
    assert "lod auto at the local views, shown passes" in text
