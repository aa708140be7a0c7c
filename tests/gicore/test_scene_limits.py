"""Every number of a scene spec has a finite, physically sensible range and a strict type: a value outside it is
refused when the spec loads, naming the file and the field, instead of overflowing in a render later."""

from __future__ import annotations

from pathlib import Path

import pytest

from gicore.scene import NAME_MAX, OBJECTS_MAX, SceneSpec, SceneSpecError, load_scene
from tests.gicore.test_scene import minimal
from tests.helpers.cli import assert_user_error


def _obj(**fields) -> dict:
    return {"name": "lungs", "anatomy": "lung", "detail": 0.3} | fields


def _light(**fields) -> dict:
    return {"position": [0, 2, 0], "intensity": 5.0} | fields


@pytest.mark.parametrize(
    "data,field",
    [
        pytest.param(minimal(objects=[_obj(height=1e308)]), r"objects\.0\.height", id="height_1e308"),
        pytest.param(minimal(objects=[_obj(height=1e-9)]), r"objects\.0\.height", id="height_1e-9"),
        pytest.param(minimal(objects=[_obj(seed=-1)]), r"objects\.0\.seed", id="seed_negative"),
        pytest.param(minimal(objects=[_obj(seed=2**32)]), r"objects\.0\.seed", id="seed_2_32"),
        pytest.param(minimal(objects=[_obj(seed=True)]), r"objects\.0\.seed", id="seed_bool"),
        pytest.param(minimal(objects=[_obj(seed="3")]), r"objects\.0\.seed", id="seed_string"),
        pytest.param(minimal(objects=[_obj(seed=2.5)]), r"objects\.0\.seed", id="seed_fraction"),
        pytest.param(minimal(objects=[_obj(position=[0, 1e308, 0])]), r"objects\.0\.position\.1", id="position"),
        pytest.param(minimal(objects=[_obj(rotate_y=1e20)]), r"objects\.0\.rotate_y", id="rotate_y"),
        pytest.param(minimal(objects=[_obj(detail="1")]), r"objects\.0\.detail", id="detail_string"),
        pytest.param(minimal(objects=[_obj(albedo=[True, 0.5, 0.5])]), r"objects\.0\.albedo\.0", id="albedo_bool"),
        pytest.param(minimal(objects=[_obj(name="a" * (NAME_MAX + 1))]), r"objects\.0\.name", id="name_too_long"),
        pytest.param(
            minimal(objects=[_obj(name=f"o{i}") for i in range(OBJECTS_MAX + 1)]), "objects", id="too_many_objects"
        ),
        pytest.param(minimal(light=_light(position=[0, 1e308, 0])), r"light\.position", id="light_pos"),
        pytest.param(minimal(light=_light(intensity=1e308)), r"light\.intensity", id="intensity"),
        pytest.param(minimal(light=_light(size=1e308)), r"light\.size", id="size"),
        pytest.param(
            minimal(light=_light(amplitude=[1e308, 0])),
            r"light\.amplitude\.0",
            id="amplitude",
        ),
        pytest.param(
            minimal(light=_light(period=[1e-320, 10])),
            r"light\.period\.0",
            id="period_subnormal",
        ),
        pytest.param(
            minimal(light=_light(period=[100, 1e308])),
            r"light\.period\.1",
            id="period_1e308",
        ),
        pytest.param(minimal(camera={"radius": 1e308}), r"camera\.radius", id="camera_radius"),
        pytest.param(minimal(camera={"height": 1e308}), r"camera\.height", id="camera_height"),
        pytest.param(minimal(camera={"target": [0, 0, -1e308]}), r"camera\.target\.2", id="camera_target"),
        pytest.param(minimal(camera={"azimuth_center": 1e308}), r"camera\.azimuth_center", id="azimuth_center"),
        pytest.param(minimal(camera={"local_fov": True}), r"camera\.local_fov", id="fov_bool"),
        pytest.param(minimal(resolution=True), "resolution", id="resolution_bool"),
        pytest.param(minimal(resolution="256"), "resolution", id="resolution_string"),
    ],
)
def test_out_of_range_or_mistyped_number_names_the_field(data: dict, field: str) -> None:
    with pytest.raises(SceneSpecError, match=field):
        SceneSpec.from_dict(data)


def test_the_sensible_ranges_keep_what_scenes_use() -> None:
    spec = SceneSpec.from_dict(
        minimal(
            objects=[_obj(seed=2**32 - 1, height=0.01, position=[-5.0, 0.0, 999.0], rotate_y=-360)],
            light={"position": [0, 2, 0], "intensity": 5, "size": 0.3, "amplitude": [1.0, -0.5], "period": [1, 1e6]},
            camera={"radius": 50.0, "height": -3, "azimuth_center": 180},
        )
    )
    assert spec.objects[0].seed == 2**32 - 1 and spec.light.intensity == 5.0 and spec.camera.height == -3.0


SPEC = (
    'name = "s"\n[[objects]]\nname = "lungs"\nanatomy = "lung"\n{obj}\n[light]\nposition = [0, 2, 0]\nintensity = 3.0\n'
)


def test_a_spec_file_with_height_1e308_and_seed_minus_1_is_one_error_naming_file_and_fields(tmp_path: Path) -> None:
    path = tmp_path / "huge.toml"
    path.write_text(SPEC.format(obj="height = 1e308\nseed = -1"))
    with pytest.raises(SceneSpecError) as err:
        load_scene(path)
    message = str(err.value)
    assert message.startswith(f"{path}: 2 invalid field(s): ") and "\n" not in message
    assert "objects.0.height" in message and "objects.0.seed" in message


def test_a_command_given_such_a_spec_fails_with_one_line(tmp_path: Path) -> None:
    (tmp_path / "huge.toml").write_text(SPEC.format(obj="height = 1e308"))
    line = assert_user_error(["gicore-dataset", "huge.toml", "--out", "ds"], "objects.0.height", tmp_path)
    assert "huge.toml" in line
