"""Randomised training scenes and their shapes: closed outward meshes of every kind, draws that are a pure function
of (seed, index) within their ranges, a card that records them, and `gicore-dataset --random` rendering them."""

from __future__ import annotations

import colorsys
import json
from pathlib import Path

import numpy as np
import pytest

from gicore.dataset import read_meta
from gicore.scene_draws import FLOOR_HALF, RANGES, draw_scene, draw_scenes
from gicore.shapes import SHAPE_KINDS, Shape, deformed

PARAMS = {
    "box": {"x": 0.8, "y": 0.5, "z": 0.4},
    "plate": {"x": 1.0, "y": 0.04, "z": 0.6},
    "cylinder": {"radius": 0.3},
    "cone": {"radius": 0.4},
    "capsule": {"radius": 0.3, "length": 0.6},
    "ellipsoid": {"x": 0.5, "y": 0.8, "z": 0.4},
    "torus": {"minor": 0.3},
    "tube": {"radius": 0.4, "wall": 0.03, "height": 0.8},
    "bowl": {"thickness": 0.04, "opening": 100.0},
    "anatomy": {"organ": "vessels", "seed": 5, "scale": [1.2, 0.8, 1.0], "twist": 30.0, "bend": 0.3},
}


@pytest.mark.parametrize("kind", SHAPE_KINDS)
def test_every_shape_is_a_closed_mesh_facing_out(kind: str) -> None:
    import trimesh

    mesh = Shape(kind, PARAMS[kind]).mesh()
    closed = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    assert closed.is_watertight and closed.volume > 0  # positive volume: the faces wind outward


def test_primitives_stand_y_up_subdivided_and_tilt_as_asked() -> None:
    box = Shape("box", PARAMS["box"]).mesh()
    np.testing.assert_allclose(np.ptp(box.vertices, axis=0), (0.8, 0.5, 0.4), atol=1e-6)
    edges = box.vertices[box.faces] - box.vertices[np.roll(box.faces, 1, axis=1)]
    assert np.linalg.norm(edges, axis=-1).max() <= 0.06 * 0.8 + 1e-6  # a face's normal stays its own
    tilted = Shape("cylinder", PARAMS["cylinder"], tilt=(90.0, 0.0)).mesh()
    np.testing.assert_allclose(np.ptp(tilted.vertices, axis=0), (0.6, 0.6, 1.0), atol=1e-3)  # lying along z
    with pytest.raises(ValueError, match="unknown shape 'blob'"):
        Shape("blob")


def test_deformation_scales_twists_and_bends() -> None:
    cube = Shape("box", {"x": 1.0, "y": 1.0, "z": 1.0}).mesh()
    plain = deformed(cube, (1.0, 1.0, 1.0), 0.0, 0.0)
    np.testing.assert_allclose(plain.vertices, cube.normalized(1.0).vertices, atol=1e-6)
    wide = deformed(cube, (2.0, 1.0, 0.5), 0.0, 0.0)
    np.testing.assert_allclose(np.ptp(wide.vertices, axis=0), (2.0, 1.0, 0.5), atol=1e-5)
    bent = deformed(cube, (1.0, 1.0, 1.0), 0.0, 0.5)
    top, base = bent.vertices[:, 1] > 0.999, bent.vertices[:, 1] < 1e-3
    assert bent.vertices[top, 0].mean() - bent.vertices[base, 0].mean() == pytest.approx(0.5, abs=1e-3)


def test_a_scene_is_a_pure_function_of_seed_and_index_within_its_ranges(tmp_path: Path) -> None:
    spec, draws = draw_scene(3, 7, tmp_path / "a")
    again, draws_again = draw_scene(3, 7, tmp_path / "b")
    assert draws == draws_again
    assert spec.model_dump(exclude={"objects"}) == again.model_dump(exclude={"objects"})
    for mesh_a, mesh_b in zip(sorted((tmp_path / "a").iterdir()), sorted((tmp_path / "b").iterdir())):
        assert mesh_a.read_bytes() == mesh_b.read_bytes()
    specs = [draw_scene(3, i, tmp_path / "many")[0] for i in range(12)]
    assert len({s.model_dump_json(exclude={"name"}) for s in specs}) == 12
    assert {s.environment for s in specs} == set(RANGES["environment"])
    for s in specs:
        top = max(o.height for o in s.objects)
        assert s.light.position[1] - s.light.amplitude[1] >= top + 0.3 - 1e-9  # the light swings above them
        assert RANGES["objects"][0] <= len(s.objects) <= RANGES["objects"][1]
        for o in s.objects:
            assert max(abs(o.position[0]), abs(o.position[2])) <= FLOOR_HALF[s.environment] + 1e-9
            h, sat, v = colorsys.rgb_to_hsv(*o.albedo)
            assert RANGES["value"][0] - 1e-3 <= v <= RANGES["value"][1] + 1e-3 and 0 <= sat <= 1


def test_the_card_records_every_draw_and_the_ranges(tmp_path: Path) -> None:
    specs = draw_scenes(4, 3, tmp_path)
    doc = json.loads((tmp_path / "random_scenes.json").read_text())
    assert (doc["seed"], doc["count"], doc["ranges"]) == (4, 3, json.loads(json.dumps(RANGES)))
    assert (
        [s["name"] for s in doc["scenes"]]
        == [s.name for s in specs]
        == ["random4_0000", "random4_0001", "random4_0002"]
    )
    assert [len(s["objects"]) for s in doc["scenes"]] == [len(s.objects) for s in specs]
    assert doc["scenes"][0]["spec"] == specs[0].to_dict()
    table = (tmp_path / "random_scenes.md").read_text()
    assert table.count("| random4_") == sum(len(s.objects) for s in specs)
    assert all((tmp_path / s.name / "meshes").is_dir() for s in specs)


def test_gicore_dataset_renders_randomised_scenes(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from gicore.dataset_cli import app

    argv = ["--random", "2", "--train", "1", "--val", "1", "--resolution", "16", "--spp", "2", "--no-denoise"]
    result = CliRunner().invoke(app, [*argv, "--seed", "9", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    for name in ("random9_0000", "random9_0001"):
        meta = read_meta(tmp_path / name)
        assert meta.scene["name"] == name and len(meta.frames) == 2 and meta.seed == 9
    assert json.loads((tmp_path / "random_scenes.json").read_text())["count"] == 2
    result = CliRunner().invoke(app, ["--out", str(tmp_path / "none")])  # (exit 2 through main: test_cli_errors)
    assert "no scenes given" in str(result.exception) and not (tmp_path / "none").exists()
