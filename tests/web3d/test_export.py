"""web3d.export: the viewer's assets are the scene's own triangles, GLRenderer's shaders as GLSL ES 3.00, the
fly-through as a path file, the scene's camera space and light box, and the shadow setup GLRenderer fits for
each light."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gicore.geometry import scene_objects
from gicore.gl.renderer import object_bounds
from gicore.path_file import read_path_file
from gicore.paths import DEFAULT_LIGHT_CELL, camera_path, light_position, light_range, path_views
from gicore.scene import load_scene
from web3d.export import VERTEX_FLOATS, export_assets, shadow_setup
from web3d.shaders import encode_writes, to_es


@pytest.fixture(scope="module")
def exported(make_spec, tmp_path_factory: pytest.TempPathFactory) -> tuple:
    spec = make_spec(with_box=True, light={"amplitude": [0.5, 0.2]})
    folder = tmp_path_factory.mktemp("assets")
    spec_file = folder / "scene.json"
    spec_file.write_text(json.dumps(spec.to_dict()))
    header = export_assets(spec_file, folder / "out", frames=5, orbit_frames=10)
    return load_scene(spec_file), header, folder / "out"


def test_the_exported_triangles_are_the_scenes(exported) -> None:
    spec, header, out = exported
    data = (out / "scene.bin").read_bytes()
    n_vertices, n_indices = header["vertices"]["count"], header["indices"]["count"]
    n_casters, n_caster_indices = header["shadow_vertices"]["count"], header["shadow_indices"]["count"]
    assert len(data) == n_vertices * VERTEX_FLOATS * 4 + n_indices * 4 + n_casters * 12 + n_caster_indices * 4
    # the shadow casters: meshes under MIN_TRIANGLES (these) are not decimated, so every triangle casts
    assert n_caster_indices == sum(3 * o.mesh.n_triangles for o in scene_objects(spec))
    vertices = np.frombuffer(data, np.float32, n_vertices * VERTEX_FLOATS).reshape(-1, VERTEX_FLOATS)
    indices = np.frombuffer(data, np.uint32, n_indices, header["indices"]["offset"]).reshape(-1, 3)
    objects = scene_objects(spec)
    expected = np.concatenate([o.mesh.vertices[o.mesh.faces] for o in objects])  # T x 3 corners x 3
    got = vertices[indices][..., :3]
    assert got.shape == expected.shape
    # the same triangles (each with its corners in order), in any order
    key = lambda tris: np.sort(np.round(tris.reshape(len(tris), -1), 5).view("f4,f4,f4,f4,f4,f4,f4,f4,f4"), axis=0)  # noqa: E731
    assert np.array_equal(key(got), key(expected))
    normals = vertices[:, 3:6]
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    # the closed meshes (sphere, box) come first and are drawn culled; the ground quad after
    assert header["indices"]["culled"] == 3 * sum(o.mesh.n_triangles for o in objects[:2])


def test_the_programs_are_glsl_es_300_and_the_path_is_the_clients(exported) -> None:
    spec, header, out = exported
    for name, program in header["programs"].items():
        for stage, source in program.items():
            assert source.startswith("#version 300 es\nprecision highp float;"), (name, stage)
            assert "#version 330" not in source
    assert "#define PASS_GBUFFER" in header["programs"]["di_gbuffer"]["fragment"]
    assert "#define CUBE_SHADOW" in header["programs"]["di_cube"]["fragment"]
    with pytest.raises(ValueError, match="330 core"):
        to_es("#version 450\nvoid main() {}")
    assert json.loads((out / "path.json").read_text())["format"] == "gigan-path/1"
    path = read_path_file(out / "path.json", spec)
    views = path_views(spec, 5, 10, 0, spec.camera.local_fov, header["resolution"])
    assert path.views(header["resolution"]) == views  # exactly the clients' cameras and lights
    assert len({light for _, _, light in path.frames}) == 5  # the light moves
    model = json.loads((out / "model" / "model.json").read_text())
    assert (out / "model" / "model.onnx").stat().st_size > 1e6 and model["resolution"] == header["resolution"]


def test_the_warp_fill_and_blend_programs_are_the_desktop_sources_as_glsl_es_300(exported) -> None:
    """shaders.json: every program of the page's warps, hole filling, composition and GIGAN's encoding is a
    source of gicore/gl/glsl or web3d/glsl with its includes resolved, ported by to_es alone."""
    from gicore.gl.sources import glsl
    from gicore.tonemap import LINEAR_OF_U8

    shaders = json.loads((exported[2] / "shaders.json").read_text())
    assert shaders["format"] == "gigan-web-shaders/1"
    programs = shaders["programs"]
    for name, program in programs.items():
        for stage, source in program.items():
            assert source.startswith("#version 300 es\nprecision highp float;"), (name, stage)
            assert "#include" not in source and "#version 330" not in source, (name, stage)
    assert programs["structure_warp"]["fragment"].endswith(glsl("structure_warp.frag").split("\n", 1)[1])
    assert programs["pull"]["vertex"] == to_es(glsl("fullscreen.vert"))
    assert "#define TONEMAP" in programs["compose"]["fragment"]
    assert 0 < shaders["structure"]["u_step"] and shaders["pixel"]["empty"] > 1e30
    # the cloud map's point cloud: the desktop bind's source for 8-bit maps, decoding by the host decode's table
    assert programs["pixel_cloud"]["fragment"] == to_es(glsl("pixel_cloud.frag", {"DISPLAY": None}))
    assert np.array_equal(np.float32(shaders["pixel"]["linear_of_u8"]), LINEAR_OF_U8)
    assert encode_writes(["di", "depth"]) == (1, "o0 = vec4(e_di[0], e_di[1], e_di[2], e_depth[0]);")
    targets, writes = encode_writes(["di", "albedo", "normal", "depth", "mask"])
    assert targets == 3 and writes.endswith("o2 = vec4(e_normal[2], e_depth[0], e_mask[0], 0.0);")


@pytest.fixture(scope="module")
def gl_renderer(make_spec):
    from gicore.gl import GLRenderer, RasterUnavailable

    try:
        return GLRenderer(make_spec(with_box=True), 32, shadow_size=256)
    except RasterUnavailable as err:
        pytest.skip(f"no OpenGL context: {err}")


@pytest.mark.parametrize("light", [(0.8, 2.6, 1.2), (0.0, 0.5, 0.0)], ids=["fitted", "cube"])
def test_shadow_setup_is_glrenderers(gl_renderer, light) -> None:
    position = np.asarray(light, dtype=np.float64)
    theirs = gl_renderer._shadow_views(position)
    ours = shadow_setup(object_bounds(gl_renderer.objects, len(gl_renderer.spec.objects)), position, 256)
    assert len(ours["views"]) == len(theirs["views"]) == (1 if light[1] > 2 else 6)
    for a, b in zip(ours["views"], theirs["views"]):
        assert np.allclose(a, np.asarray(b).T.ravel(), atol=1e-6)
    for key in ("tile", "blocker_min", "far"):
        assert ours[key] == pytest.approx(theirs[key])
    assert ours["texel"] == pytest.approx(theirs["texel"]) and tuple(ours["atlas"]) == tuple(theirs["atlas"])


def test_scene_json_holds_the_camera_space_and_the_light_box(exported) -> None:
    """The page clamps the user's camera to ``navigation`` and the light to ``light_range``: every camera and
    light the fly-through takes lies inside them, and the light box is the server's (one light cell wider)."""
    spec, header, _ = exported
    c = spec.camera
    assert header["camera"] == {"local_fov": c.local_fov, "gi_fov": c.gi_fov, "near": c.near, "far": c.far,
                                "up": [0.0, 1.0, 0.0]}  # fmt: skip
    nav = header["navigation"]
    assert nav["target"] == list(c.target) and nav["target_wobble"] == pytest.approx(0.1 * c.wobble)
    assert nav["azimuth"] is None  # the test scene's orbit is a full circle
    for camera in camera_path(spec, 400, seed=3):
        dx, dz = camera.origin[0] - c.target[0], camera.origin[2] - c.target[2]
        assert nav["radius"][0] - 1e-9 <= np.hypot(dx, dz) <= nav["radius"][1] + 1e-9
        assert nav["height"][0] - 1e-9 <= camera.origin[1] <= nav["height"][1] + 1e-9
        assert np.all(np.abs(np.subtract(camera.target[:2], c.target[:2])) <= nav["target_wobble"] + 1e-9)
    (low, high), cell = light_range(spec), DEFAULT_LIGHT_CELL
    assert header["light_range"] == [[v - cell for v in low], [v + cell for v in high]]
    lights = np.array([light_position(spec, f) for f in range(0, 5000, 7)])
    assert np.all(lights >= np.array(header["light_range"][0])) and np.all(lights <= np.array(header["light_range"][1]))
    assert header["light_rest"] == list(spec.light.position)
