"""Scene specs, built-in scenes, environments, and camera/light paths (docs/architecture.md, Scenes)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import ValidationError

from gicore import geometry
from gicore.error_policy import UserError
from gicore.paths import camera_path, light_position
from gicore.scene import SceneSpec, SceneSpecError, builtin_scenes, load_scene

PAPER_SCENES = ["digestive_cornell", "digestive_plane", "lung_cornell", "lung_plane", "vessels_plane"]


def minimal(**top) -> dict:
    data = {
        "name": "s",
        "objects": [{"name": "lungs", "anatomy": "lung", "detail": 0.3}],
        "light": {"position": [0.0, 2.0, 1.0], "intensity": 5.0},
    }
    data.update(top)
    return data


# -- built-in scenes ------------------------------------------------------------------------------------
def test_builtin_scenes_are_the_papers_five():
    assert builtin_scenes() == PAPER_SCENES


@pytest.mark.parametrize("name", PAPER_SCENES)
def test_builtin_scene_loads(name):
    spec = load_scene(name)
    assert spec.name == name
    assert spec.environment == ("cornell_box" if name.endswith("cornell") else "white_plane")
    kind = name.split("_")[0]
    assert [o.anatomy for o in spec.objects] == [{"lung": "lung", "digestive": "digestive", "vessels": "vessels"}[kind]]
    assert spec.camera.local_fov == 60.0 and spec.camera.gi_fov == 90.0
    assert spec.light.moves  # paper IV.C: the light moves along x and y
    # Round trip through plain data.
    assert SceneSpec.from_dict(spec.to_dict()) == spec


def test_load_scene_from_file_and_relative_mesh(tmp_path, sphere_mesh_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "ball.obj").write_bytes(sphere_mesh_path.read_bytes())
    (tmp_path / "scene.toml").write_text(
        'name = "mine"\nenvironment = "none"\n[[objects]]\nname = "ball"\nmesh = "meshes/ball.obj"\n'
        "[light]\nposition = [0, 2, 0]\nintensity = 3.0\n"
    )
    spec = load_scene(tmp_path / "scene.toml")
    assert spec.objects[0].mesh == tmp_path / "meshes" / "ball.obj"
    (tmp_path / "scene.json").write_text(json.dumps(spec.to_dict()))
    assert load_scene(tmp_path / "scene.json") == spec


def test_unknown_scene_name():
    with pytest.raises(SceneSpecError, match="no scene spec 'no_such_scene'.*lung_plane"):
        load_scene("no_such_scene")


# -- validation errors name the field -----------------------------------------------------------------------
@pytest.mark.parametrize(
    "mutate,field",
    [
        pytest.param(lambda d: d.update(colour="red"), "colour", id="unknown_top_field"),
        pytest.param(lambda d: d["light"].update(power=3), r"light\.power", id="unknown_light_field"),
        pytest.param(lambda d: d["objects"][0].update(scale=2), r"objects\.0\.scale", id="unknown_object_field"),
        pytest.param(lambda d: d.update(resolution="big"), "resolution", id="wrong_type_resolution"),
        pytest.param(lambda d: d["light"].update(position=[0, "up", 1]), r"light\.position", id="wrong_type_position"),
        pytest.param(lambda d: d["light"].update(position=[0, 1]), r"light\.position", id="short_position"),
        pytest.param(lambda d: d["light"].update(intensity=-1.0), r"light\.intensity", id="negative_intensity"),
        pytest.param(lambda d: d["light"].update(intensity=0.0), r"light\.intensity", id="zero_intensity"),
        pytest.param(lambda d: d["light"].update(intensity=math.nan), r"light\.intensity", id="nan_intensity"),
        pytest.param(
            lambda d: d["light"].update(position=[0, math.inf, 1]), r"light\.position", id="inf_light_position"
        ),
        pytest.param(lambda d: d["light"].update(period=[0, 10]), r"light\.period", id="zero_period"),
        pytest.param(lambda d: d["light"].pop("intensity"), r"light\.intensity", id="missing_intensity"),
        pytest.param(lambda d: d.update(environment="forest"), "environment", id="bad_environment"),
        pytest.param(lambda d: d.update(objects=[]), "objects", id="no_objects"),
        pytest.param(lambda d: d["objects"][0].update(anatomy="heart"), r"objects\.0\.anatomy", id="unknown_anatomy"),
        pytest.param(lambda d: d["objects"][0].update(name="has space"), r"objects\.0\.name", id="bad_object_name"),
        pytest.param(
            lambda d: d["objects"][0].update(albedo=[0.5, 1.5, 0.5]), r"objects\.0\.albedo", id="albedo_above_1"
        ),
        pytest.param(lambda d: d.update(camera={"gi_fov": 180.0}), r"camera\.gi_fov", id="gi_fov_180"),
        pytest.param(lambda d: d.update(camera={"local_fov": 0.0}), r"camera\.local_fov", id="local_fov_0"),
        pytest.param(lambda d: d.update(camera={"gi_fov": 1e-300}), r"camera\.gi_fov", id="gi_fov_too_narrow"),
        pytest.param(lambda d: d.update(camera={"local_fov": math.nan}), r"camera\.local_fov", id="local_fov_nan"),
        pytest.param(
            lambda d: d.update(camera={"near": 1.0, "far": 0.5}), r"near = 1, far = 0\.5", id="far_below_near"
        ),
        pytest.param(
            lambda d: d.update(camera={"near": 1e-20}),
            r"camera: near = 1e-20.*represents 1e-10 <= near < far <= 1e\+30",
            id="near_1e-20",
        ),
        pytest.param(lambda d: d.update(camera={"near": 0.0}), r"camera: near = 0,", id="near_0"),
        pytest.param(
            lambda d: d.update(camera={"far": 1e39}), r"camera: near = 0\.01, far = 1e\+39.*represents", id="far_1e39"
        ),
        pytest.param(lambda d: d.update(name="../../x"), r"name: '\.\./\.\./x' is not a name", id="scene_name_path"),
        pytest.param(lambda d: d.update(name=""), r"name: '' is not a name", id="scene_name_empty"),
        pytest.param(lambda d: d.update(name="a/b"), r"name: 'a/b' is not a name", id="scene_name_slash"),
        pytest.param(
            lambda d: d["objects"][0].update(name="../o"),
            r"objects\.0\.name: '\.\./o' is not a name",
            id="object_name_path",
        ),
        pytest.param(
            lambda d: d["objects"][0].update(anatomy=None, mesh=5), r"objects\.0\.mesh", id="mesh_is_a_number"
        ),
        pytest.param(lambda d: d.update(resolution=4), "resolution", id="resolution_too_small"),
    ],
)
def test_bad_spec_names_the_field(mutate, field):
    data = minimal()
    mutate(data)
    with pytest.raises(SceneSpecError, match=field):
        SceneSpec.from_dict(data)


def test_error_lists_every_bad_field():
    data = minimal(colour="red")
    data["light"]["intensity"] = -2.0
    with pytest.raises(SceneSpecError) as info:
        SceneSpec.from_dict(data, source="my.toml")
    msg = str(info.value)
    assert msg.startswith("my.toml: 2 invalid field(s): ")
    assert "colour" in msg and "light.intensity" in msg
    assert "\n" not in msg  # one line, as the CLI prints it
    assert isinstance(info.value, ValueError) and isinstance(info.value, UserError)


@pytest.mark.parametrize(
    "obj",
    [
        pytest.param({"name": "o", "anatomy": "lung", "mesh": "x.obj"}, id="both"),
        pytest.param({"name": "o"}, id="neither"),
    ],
)
def test_exactly_one_of_anatomy_or_mesh(obj):
    with pytest.raises(SceneSpecError, match=r"objects\.0.*anatomy.*mesh"):
        SceneSpec.from_dict(minimal(objects=[obj]))


def test_duplicate_object_names():
    objs = [{"name": "a", "anatomy": "lung"}, {"name": "a", "anatomy": "lung", "seed": 2}]
    with pytest.raises(SceneSpecError, match=r"names must be unique.*'a'"):
        SceneSpec.from_dict(minimal(objects=objs))


def test_bad_toml_is_a_spec_error_naming_the_file(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text('name = "x"\n[light\nposition = [0, 1, 2]\n')
    with pytest.raises(SceneSpecError, match=r"broken\.toml.*cannot parse"):
        load_scene(path)
    bad_json = tmp_path / "broken.json"
    bad_json.write_text('{"name": "x", ')
    with pytest.raises(SceneSpecError, match=r"broken\.json.*cannot parse"):
        load_scene(bad_json)


def test_bad_field_in_a_file_names_file_and_field(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(
        'name = "x"\n[[objects]]\nname = "l"\nanatomy = "lung"\n[light]\nposition = [0, 1, 2]\nintensity = -3.0\n'
    )
    with pytest.raises(SceneSpecError, match=r"(?s)s\.toml.*light\.intensity"):
        load_scene(path)


MESH_FILES = {
    "missing": None,
    "empty": b"",
    "text": b"this is not a mesh\n",
    "nan_vertex": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 1\nf 1 2 3\nf 1 2 4\n",
    "inf_vertex": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 inf 1\nf 1 2 3\nf 1 2 4\n",
    "flat": b"v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n",
}


@pytest.mark.parametrize(
    "kind,reason",
    [
        ("missing", "not found"),
        ("empty", "no triangles"),
        ("text", "no triangles"),
        ("nan_vertex", r"1 vertex\(es\) with NaN or Inf coordinates, e\.g\. vertex 4"),
        ("inf_vertex", r"1 vertex\(es\) with NaN or Inf coordinates, e\.g\. vertex 4"),
        ("flat", "flat in y"),
    ],
)
def test_bad_mesh_is_refused_when_the_spec_loads(tmp_path, kind, reason):
    """Not at render time: the spec names the object, the file and what is wrong with it."""
    path = tmp_path / "organ.obj"
    if MESH_FILES[kind] is not None:
        path.write_bytes(MESH_FILES[kind])
    spec_file = tmp_path / "scene.toml"
    spec_file.write_text(
        'name = "s"\n[[objects]]\nname = "organ"\nmesh = "organ.obj"\n[light]\nposition = [0, 2, 0]\nintensity = 3.0\n'
    )
    with pytest.raises(
        SceneSpecError, match=rf"scene\.toml: 1 invalid field\(s\): objects\.0: mesh file {path}: .*{reason}"
    ):
        load_scene(spec_file)


def test_spec_is_frozen():
    spec = SceneSpec.from_dict(minimal())
    with pytest.raises(ValidationError, match="frozen"):
        spec.name = "other"  # type: ignore[misc]


# -- environments ----------------------------------------------------------------------------------------------
def test_white_plane_has_no_walls():
    objs = geometry.environment_objects("white_plane")
    assert [o.name for o in objs] == ["ground"]
    ground = objs[0].mesh
    assert ground.n_triangles == 2
    assert np.all(ground.vertices[:, 1] == 0.0)
    np.testing.assert_allclose(ground.vertex_normals(), np.tile([0.0, 1.0, 0.0], (4, 1)), atol=1e-6)


def test_cornell_box_has_five_quads():
    objs = geometry.environment_objects("cornell_box")
    assert sorted(o.name for o in objs) == ["back", "ceiling", "floor", "left", "right"]
    for o in objs:
        assert o.mesh.n_triangles == 2 and len(o.mesh.vertices) == 4, o.name
    # Red left wall, green right wall, white elsewhere.
    albedo = {o.name: o.albedo for o in objs}
    assert albedo["left"][0] > albedo["left"][1] and albedo["right"][1] > albedo["right"][0]
    # Every wall faces the inside of the box (its normal points towards the box centre).
    centre = np.array([0.0, geometry.BOX_HEIGHT / 2, 0.0])
    for o in objs:
        n = o.mesh.vertex_normals()[0]
        assert np.dot(n, centre - o.mesh.vertices.mean(0)) > 0, o.name


def test_empty_environment():
    assert geometry.environment_objects("none") == []


def test_scene_objects_user_mesh_placed(make_spec):
    spec = make_spec(with_box=True)
    objs = geometry.scene_objects(spec)
    assert [o.name for o in objs] == ["ball", "box", "ground"]
    lo, hi = objs[0].mesh.bounds
    assert lo[1] == pytest.approx(geometry.SEAT_GAP, abs=1e-6) and hi[1] == pytest.approx(
        1.0 + geometry.SEAT_GAP, abs=1e-6
    )
    lo, hi = objs[1].mesh.bounds
    assert hi[1] == pytest.approx(0.8 + geometry.SEAT_GAP, abs=1e-6)
    np.testing.assert_allclose((lo[[0, 2]] + hi[[0, 2]]) / 2, [0.9, -0.4], atol=0.05)


def test_anatomy_object_mesh_is_placed_and_cached_per_process():
    obj = SceneSpec.from_dict(minimal()).objects[0]
    mesh = geometry.object_mesh(obj)
    assert geometry.object_mesh(obj) is mesh
    assert mesh.n_triangles > 100
    assert mesh.bounds[0][1] == pytest.approx(geometry.SEAT_GAP, abs=1e-6)
    assert mesh.bounds[1][1] == pytest.approx(obj.height + geometry.SEAT_GAP, rel=1e-5)


@pytest.mark.parametrize("name", PAPER_SCENES)
def test_builtin_scene_builds_and_renders_at_low_detail(name):
    from gicore.render import Renderer

    data = load_scene(name).to_dict()
    for obj in data["objects"]:
        obj["detail"] = 0.3
    spec = SceneSpec.from_dict(data)
    objs = geometry.scene_objects(spec)
    n_env = 5 if spec.environment == "cornell_box" else 1
    assert len(objs) == len(spec.objects) + n_env
    r = Renderer(spec, 24)
    cam = camera_path(spec, 1, resolution=24)[0]
    gb = r.render_gbuffers(cam)
    assert all(np.all(np.isfinite(v)) for v in gb.values())
    # The organ is in view: some pixels hit it (thin tubes cover few pixels at this resolution).
    lo, hi = objs[0].mesh.bounds
    p = gb["position"]
    organ = (gb["mask"][..., 0] > 0) & np.all((p >= lo - 1e-4) & (p <= hi + 1e-4), axis=-1) & (p[..., 1] > 0.05)
    assert organ.sum() >= 5


# -- camera path and light schedule ----------------------------------------------------------------------------
def _steps(cams) -> np.ndarray:
    origins = np.array([c.origin for c in cams])
    return np.linalg.norm(np.diff(origins, axis=0), axis=1)


@pytest.mark.parametrize("name", PAPER_SCENES)
def test_camera_path_is_smooth(name):
    spec = load_scene(name)
    n = 200
    cams = camera_path(spec, n, seed=4)
    assert len(cams) == n
    steps = _steps(cams)
    c = spec.camera
    # Bound from the path's construction: arc length per frame plus the wobble's radial/height speed.
    r_max = c.radius * (1 + c.wobble)
    arc = 2 * math.pi * r_max * (c.azimuth_range / 360.0) * (math.pi if c.azimuth_range < 360 else 1.0)
    wobble = 2 * math.pi * 3 * max(c.radius, abs(c.height)) * c.wobble * 2
    bound = (arc + wobble) / n
    assert steps.max() <= bound, (steps.max(), bound)
    # No jumps: doubling the frame count halves the largest step (continuity).
    steps2 = _steps(camera_path(spec, 2 * n, seed=4))
    assert steps2.max() <= 0.6 * steps.max()
    assert steps.max() <= 4.0 * np.median(steps)
    # Every camera looks at the scene and is valid.
    for cam in cams[::20]:
        assert np.linalg.norm(np.subtract(cam.target, c.target)) < 0.2
        assert cam.fov == c.gi_fov and cam.width == spec.resolution


def test_camera_path_seeds_and_options():
    spec = load_scene("lung_plane")
    a = camera_path(spec, 10, seed=0)
    b = camera_path(spec, 10, seed=0)
    c = camera_path(spec, 10, seed=1)
    assert a == b
    assert all(np.linalg.norm(np.subtract(x.origin, y.origin)) > 1e-3 for x, y in zip(a, c))
    custom = camera_path(spec, 3, fov=60.0, resolution=48)
    assert all(cam.fov == 60.0 and cam.width == cam.height == 48 for cam in custom)
    with pytest.raises(ValueError, match="n_frames"):
        camera_path(spec, 0)


def test_cornell_path_stays_on_the_open_side():
    spec = load_scene("lung_cornell")
    for cam in camera_path(spec, 100, seed=2):
        x, _, z = cam.origin
        az = math.degrees(math.atan2(x, z))
        assert abs(az) <= spec.camera.azimuth_range / 2 + 1e-6
        assert z > geometry.BOX_HALF  # outside the open front of the box


def test_light_schedule():
    spec = load_scene("lung_plane")
    p0 = light_position(spec, 0)
    assert p0 == pytest.approx(spec.light.position)
    xs = np.array([light_position(spec, f) for f in range(400)])
    ax, ay = spec.light.amplitude
    assert xs[:, 0].max() - xs[:, 0].min() == pytest.approx(2 * ax, rel=0.01)
    assert xs[:, 1].max() - xs[:, 1].min() == pytest.approx(2 * ay, rel=0.01)
    assert np.all(xs[:, 2] == spec.light.position[2])
    assert np.abs(np.diff(xs, axis=0)).max() < 0.05  # smooth
    static = SceneSpec.from_dict(minimal())
    assert not static.light.moves
    assert {light_position(static, f) for f in range(0, 500, 50)} == {tuple(static.light.position)}


def test_mesh_that_is_not_a_path_names_the_field(tmp_path):
    """``mesh = 5`` was a TypeError while resolving relative mesh paths."""
    spec_file = tmp_path / "scene.toml"
    spec_file.write_text(
        'name = "s"\n[[objects]]\nname = "organ"\nmesh = 5\n[light]\nposition = [0, 2, 0]\nintensity = 3.0\n'
    )
    with pytest.raises(
        SceneSpecError, match=r"scene\.toml: 1 invalid field\(s\): objects\.0\.mesh: Input is not a valid path"
    ):
        load_scene(spec_file)


def test_a_valid_mesh_loads_once_for_spec_and_renderer(sphere_mesh_path):
    """The spec validation reads the mesh; building the scene's geometry reuses that read."""
    from gicore.mesh import _load_mesh

    _load_mesh.cache_clear()
    spec = SceneSpec.from_dict(minimal(objects=[{"name": "ball", "mesh": str(sphere_mesh_path)}]))
    geometry.object_mesh.cache_clear()
    geometry.scene_objects(spec)
    assert _load_mesh.cache_info().misses == 1 and _load_mesh.cache_info().hits >= 1


def test_relative_mesh_paths_do_not_depend_on_the_working_directory(tmp_path, sphere_mesh_path, monkeypatch):
    """A dataset's meta.json stores the spec: loading the same spec file from another folder must give the
    same spec, or a resumed run would be refused as "made with other settings"."""
    (tmp_path / "ball.obj").write_bytes(sphere_mesh_path.read_bytes())
    (tmp_path / "s.toml").write_text(
        'name = "s"\n[[objects]]\nname = "b"\nmesh = "ball.obj"\n[light]\nposition = [0, 2, 0]\nintensity = 3.0\n'
    )
    monkeypatch.chdir(tmp_path)
    here = load_scene("s.toml")
    monkeypatch.chdir(tmp_path.parent)
    assert load_scene(f"{tmp_path.name}/s.toml") == here and here.objects[0].mesh.is_absolute()
