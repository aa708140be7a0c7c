"""The render cache shared between processes: one entry per spec and parameters, GT rendered once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gicore.camera import Camera
from gicore.render_cache import RenderCache

CAM = Camera((0.0, 1.0, 2.4), (0.0, 0.5, 0.0), width=16, height=16)


def test_an_entry_is_written_once_and_read_back_exactly(tmp_path: Path, sphere_spec) -> None:
    cache = RenderCache(tmp_path / "c", sphere_spec)
    calls = []

    def render() -> dict[str, np.ndarray]:
        calls.append(1)
        return {"gt": np.random.default_rng(0).random((16, 16, 3), dtype=np.float32), "ms": np.array(3.5)}

    first = cache.fetch(("gt", CAM, [1.0, 2.0, 3.0], 4), render)
    again = RenderCache(tmp_path / "c", sphere_spec).fetch(("gt", CAM, [1.0, 2.0, 3.0], 4), render)
    assert len(calls) == 1 and len(list((tmp_path / "c").iterdir())) == 1
    assert again["gt"].dtype == np.float32 and np.array_equal(first["gt"], again["gt"]) and float(again["ms"]) == 3.5


def test_every_part_of_the_key_and_the_spec_name_their_own_entry(tmp_path: Path, make_spec, sphere_spec) -> None:
    cache = RenderCache(tmp_path, sphere_spec)
    keys = [
        ("gt", CAM, [1.0, 2.0, 3.0], 4),
        ("gt", Camera((0.0, 1.0, 2.4), (0.0, 0.5, 0.0), width=32, height=32), [1.0, 2.0, 3.0], 4),
        ("gt", CAM, [1.0, 2.0, 3.5], 4),
        ("gt", CAM, [1.0, 2.0, 3.0], 8),
        ("gi_map", CAM, [1.0, 2.0, 3.0], 4),
    ]
    paths = {cache.path(k) for k in keys}
    other_scene = RenderCache(tmp_path, make_spec(light={"intensity": 13.0}))
    assert len(paths | {other_scene.path(keys[0])}) == len(keys) + 1
    assert cache.path(("gt", CAM, [np.float32(1.0), 2.0, 3.0], 4)) == cache.path(keys[0])  # numpy scalars as floats
    with pytest.raises(KeyError):
        cache[keys[0]]


def test_a_file_where_the_folder_belongs_is_refused(tmp_path: Path, sphere_spec) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(ValueError, match="is a file"):
        RenderCache(tmp_path / "f", sphere_spec)


def test_ground_truth_through_the_store_path_traces_each_frame_once(tmp_path: Path, renderer, sphere_spec) -> None:
    """Two scorers (two client runs) along one view: the second reads the first's GT, bit for bit."""
    from gicore.ground_truth import GroundTruth

    store = RenderCache(tmp_path, sphere_spec)
    cam = Camera((0.0, 1.2, 2.4), (0.0, 0.5, 0.0), width=renderer.resolution, height=renderer.resolution)
    light = (0.8, 2.6, 1.2)
    first = GroundTruth(renderer, 1, spp=2, denoise=False, seed=3, store=store).reference(0, cam, light)
    written = {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    second = GroundTruth(renderer, 1, spp=2, denoise=False, seed=3, store=store).reference(0, cam, light)
    assert np.array_equal(first, second) and {p: p.stat().st_mtime_ns for p in tmp_path.iterdir()} == written
    other_frame = GroundTruth(renderer, 1, spp=2, denoise=False, seed=3, store=store).reference(1, cam, light)
    assert len(list(tmp_path.iterdir())) == 2 and not np.array_equal(first, other_frame)  # frames differ in seed
