"""`bench render`'s client raster passes: OpenGL (full detail and lod auto) beside Mitsuba in one run, with the
level lod auto drew and its G-buffer error."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.render_bench import (
    CLIENT_PASSES,
    GL_LODS,
    GPU_DRAW,
    PARTS,
    RenderBenchConfig,
    measure_client_passes,
)
from gicore.error_policy import UserError
from gicore.present.markdown import tables_text
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
            # the draw calls alone, timed on the GPU in calls of their own: a part of a pass's wall time (within
            # the run's noise), not a unit slip (ns or s for ms) or an unread query
            assert 0 < get("gl", f"{stage}{GPU_DRAW}", "median", lod=lod) < 3 * gl
            assert get("gl", f"{stage}{GPU_DRAW}", "n", lod=lod) == 2
    for view in ("gi", "local", "local_shown"):
        assert 0 <= get("gl", "lod_level", "mean", view=view) <= get("gl", "lod_level", "max", view=view) <= 5
        for channel in ("normal", "depth", "coverage"):
            mean, top = (get("gl", f"lod_error_{channel}", stat, view=view) for stat in ("mean", "max"))
            assert 0 <= mean <= top < 0.05  # within the auto bound's order (3e-3 normal), not a broken render
    # the wide GI camera sees the lungs smaller than the local camera, so it may draw a coarser level
    assert get("gl", "lod_level", "mean", view="gi") >= get("gl", "lod_level", "mean", view="local")
    # the shown passes' looser bound never draws a finer level than the model-input bound at the same views
    assert get("gl", "lod_level", "mean", view="local_shown") >= get("gl", "lod_level", "mean", view="local")
    text = tables_text(PARTS, rows, 2)
    assert "### lung_plane, 32²" in text and text.count("| gi_camera |") == 1 and "lod auto at the gi views" in text
    assert "lod auto at the local views, shown passes" in text


def test_client_table_keeps_each_scene_to_its_own_rows() -> None:
    """Two scenes at one resolution: each table shows its own scene's times (it once showed the first
    scene's under every heading)."""
    rows = []
    for scene, ms in (("lung_plane", 1.5), ("vessels_plane", 7.25)):
        for lod in GL_LODS:
            config = {"resolution": 256, "pass_set": "client", "lod": lod}
            for stage in CLIENT_PASSES:
                rows.append({"system": "gl", "scene": scene, "metric": stage, "stat": "median", "value": ms,
                             "config": config})  # fmt: skip
                rows.append({"system": "gl", "scene": scene, "metric": f"{stage}{GPU_DRAW}", "stat": "median",
                             "value": ms / 10, "config": config})  # fmt: skip
    text = tables_text(PARTS, rows, 2)
    lung, vessels = text.split("### vessels_plane, 256²")
    assert "| gi_camera | 1.5 (—) | 0.15 | 1.5 (—) | 0.15 | — |" in lung and "7.2" not in lung
    assert "| gi_camera | 7.2 (—) | 0.72 | 7.2 (—) | 0.72 | — |" in vessels and "1.5 (" not in vessels


@pytest.mark.parametrize(
    ("renderers", "gl_resolutions", "message"),
    [
        (("gl", "vulkan"), (256,), "--renderers 'vulkan' is not a renderer"),
        (("gl", "gl"), (256,), "must name each renderer once"),
        ((), (256,), "must name each renderer once"),
        (("gl",), (), "times nothing"),
    ],
)
def test_renderers_are_checked(renderers, gl_resolutions, message) -> None:
    with pytest.raises(UserError, match=message):
        RenderBenchConfig(renderers=renderers, gl_resolutions=gl_resolutions)
