"""Scene specifications: validated plain data (TOML or JSON) describing one scene (docs/architecture.md, Scenes).

A spec names its objects (procedural anatomy or a user mesh), the environment (a white ground plane,
a Cornell box, or nothing), one light and the camera fly-through. Built-in specs for the paper's five
scenes live in ``gicore/scenes/*.toml`` and load by name::

    spec = load_scene("lung_plane")            # built-in
    spec = load_scene("my_scene.toml")         # a file
    spec = SceneSpec.from_dict({...})          # plain dict

Invalid specs raise :class:`SceneSpecError` (a :class:`~gicore.error_policy.UserError`) naming each offending
field. User meshes are read and checked when the spec loads, not when the first frame renders.
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict, ValidationError, model_validator

from gicore.anatomy import AnatomyKind
from gicore.camera import FAR_MAX, FOV_MIN, NEAR_MIN
from gicore.error_policy import RESOLUTION_MAX, RESOLUTION_MIN, SEED_MAX, UserError
from gicore.mesh import load_mesh

BUILTIN_DIR = Path(__file__).parent / "scenes"
#: Every number of a spec has a finite range in which it means something physical, so that a typo (1e308, a
#: negative seed) is refused naming its field instead of overflowing in the renderer. Scene units: the paper's
#: objects are 1-1.5 tall; the renderer's ground plane and Cornell box span a few units.
EXTENT = 1e3  # largest |coordinate| of a position or target, and largest object, light or orbit size
MIN_SIZE = 1e-3  # smallest object height and orbit radius (below it a mesh's float32 vertices collapse)
INTENSITY_MAX = 1e6  # a light 1e5 times the paper scenes' (8-12) is a typo
PERIOD_MAX = 1e6  # frames of one light swing (a period under 1 frame is no motion one could see)
NAME_MAX = 64  # characters of a scene or object name (it becomes a folder name)
OBJECTS_MAX = 64  # objects in one spec (each is a mesh that the renderers and the viewer hold in memory)
#: Numbers are strict: a quoted "1.5" or a boolean is refused rather than read as a number.
Real = Annotated[float, Strict()]
Coordinate = Annotated[Real, Field(ge=-EXTENT, le=EXTENT)]
Vec3 = tuple[Coordinate, Coordinate, Coordinate]
Unit = Annotated[Real, Field(ge=0.0, le=1.0)]
Degrees = Annotated[Real, Field(ge=-360.0, le=360.0)]
Period = Annotated[Real, Field(ge=1.0, le=PERIOD_MAX)]
Seed = Annotated[int, Strict(), Field(ge=0, le=SEED_MAX)]
NAME_PATTERN = re.compile(rf"[A-Za-z_][A-Za-z0-9_]{{0,{NAME_MAX - 1}}}")


def _check_name(name: str) -> str:
    if not NAME_PATTERN.fullmatch(name):
        raise ValueError(
            f"{name[: NAME_MAX + 8]!r} is not a name: use a letter or _ followed by letters, digits or _,"
            f" at most {NAME_MAX} in all (it names a folder and a shape)"
        )
    return name


#: Scene and object names: they become folder names (datasets, caches) and Mitsuba shape ids, so no
#: path separators, dots or empty names.
Name = Annotated[str, AfterValidator(_check_name)]


class SceneSpecError(UserError, ValueError):
    """A scene spec failed validation or could not be read; the message names the file and every bad field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ObjectSpec(_Strict):
    """One object: procedural ``anatomy`` (with seed and detail) or a user ``mesh`` file (OBJ/PLY/STL).

    The mesh is normalised to ``height`` scene units resting on the ground (see
    ``gicore.geometry.SEAT_GAP``), rotated about y by ``rotate_y`` degrees and moved by ``position``.
    A user mesh is read when the spec is validated: a missing, empty, unreadable or flat file, or one
    with a NaN/Inf vertex, is refused naming the file. The material is diffuse ``albedo`` plus a mild
    glossy lobe (rough dielectric coating with GGX ``roughness``).
    """

    name: Name
    anatomy: AnatomyKind | None = None
    mesh: Path | None = None
    seed: Seed = 0
    detail: Real = Field(1.0, gt=0.0, le=4.0)
    height: Real = Field(1.0, ge=MIN_SIZE, le=EXTENT)
    position: Vec3 = (0.0, 0.0, 0.0)
    rotate_y: Degrees = 0.0
    albedo: tuple[Unit, Unit, Unit] = (0.8, 0.35, 0.3)
    roughness: Real = Field(0.35, gt=0.0, le=1.0)

    @model_validator(mode="after")
    def _one_readable_source(self) -> ObjectSpec:
        if (self.anatomy is None) == (self.mesh is None):
            raise ValueError(f"give exactly one of 'anatomy' (one of {get_args(AnatomyKind)}) or 'mesh' (a file path)")
        if self.mesh is not None:
            try:
                load_mesh(self.mesh).normalized()  # read (cached for the renderer), finite, has triangles, not flat
            except (OSError, ValueError) as err:
                raise ValueError(str(err) if str(self.mesh) in str(err) else f"mesh file {self.mesh}: {err}") from None
        return self


class LightSpec(_Strict):
    """A point light (``size`` = 0) or a small square area light facing down (``size`` > 0).

    ``position`` is the light's rest position; ``amplitude`` (x, y) and ``period`` (frames) make it move
    along x and y as ``position + amplitude * sin(2 pi frame / period)`` (paper IV.C). Zero amplitude
    means a static light: then no light schedule enters datasets or cache keys.
    """

    position: Vec3
    intensity: Real = Field(gt=0.0, le=INTENSITY_MAX)
    size: Real = Field(0.0, ge=0.0, le=EXTENT)
    amplitude: tuple[Coordinate, Coordinate] = (0.0, 0.0)
    period: tuple[Period, Period] = (200.0, 300.0)

    @property
    def moves(self) -> bool:
        return any(a != 0.0 for a in self.amplitude)


class CameraPathSpec(_Strict):
    """A smooth fly-through around ``target``: an orbit of ``radius`` at ``height`` that sweeps
    ``azimuth_range`` degrees (centred on ``azimuth_center``), with slow seeded wobble of radius and
    height. ``local_fov`` is the client's render camera, ``gi_fov`` the GI camera (paper: 60° and 90°).
    """

    target: Vec3 = (0.0, 0.5, 0.0)
    radius: Real = Field(2.4, ge=MIN_SIZE, le=EXTENT)
    height: Coordinate = 1.2
    azimuth_center: Degrees = 0.0
    azimuth_range: Real = Field(360.0, gt=0.0, le=360.0)
    wobble: Real = Field(0.15, ge=0.0, lt=1.0)
    local_fov: Real = Field(60.0, ge=FOV_MIN, lt=180.0)
    gi_fov: Real = Field(90.0, ge=FOV_MIN, lt=180.0)
    #: Clip distances; the renderer represents [gicore.camera.NEAR_MIN, FAR_MAX] (measured, see there).
    near: Real = 0.01
    far: Real = 100.0

    @model_validator(mode="after")
    def _near_far(self) -> CameraPathSpec:
        if not NEAR_MIN <= self.near < self.far <= FAR_MAX:
            raise ValueError(
                f"near = {self.near:g}, far = {self.far:g}:"
                f" the renderer represents {NEAR_MIN:g} <= near < far <= {FAR_MAX:g}"
            )
        return self


class SceneSpec(_Strict):
    """A whole scene; see the module docstring."""

    name: Name
    objects: list[ObjectSpec] = Field(min_length=1, max_length=OBJECTS_MAX)
    environment: Literal["white_plane", "cornell_box", "none"] = "white_plane"
    light: LightSpec
    camera: CameraPathSpec = CameraPathSpec()
    resolution: Annotated[int, Strict()] = Field(256, ge=RESOLUTION_MIN, le=RESOLUTION_MAX)

    @model_validator(mode="after")
    def _unique_names(self) -> SceneSpec:
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise ValueError(f"object names must be unique, got {names}")
        return self

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "scene spec") -> SceneSpec:
        try:
            return cls.model_validate(data)
        except ValidationError as err:
            fields = []
            for e in err.errors():
                where = ".".join(str(p) for p in e["loc"]) or "(top level)"
                fields.append(f"{where}: {e['msg'].removeprefix('Value error, ')}")
            raise SceneSpecError(
                f"{source}: {len(fields)} invalid field(s): " + "; ".join(fields),
                "fix them (each field is documented in gicore/scene.py)",
            ) from None

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json")


def builtin_scenes() -> list[str]:
    """Names of the shipped scene specs (the paper's five scenes)."""
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.toml"))


def load_scene(name_or_path: str | Path) -> SceneSpec:
    """Load a built-in scene by name, or a ``.toml``/``.json`` file; relative mesh paths resolve
    against the spec file's folder (and are stored absolute)."""
    path = Path(name_or_path)
    if not path.suffix and (BUILTIN_DIR / f"{path}.toml").is_file():
        path = BUILTIN_DIR / f"{path}.toml"
    if not path.is_file():
        raise SceneSpecError(
            f"no scene spec {str(name_or_path)!r}",
            f"give a .toml/.json file or one of the built-in scenes {builtin_scenes()}",
        )
    try:
        text = path.read_text()
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, ValueError) as err:  # syntax, or bytes that are not UTF-8 text
        raise SceneSpecError(f"{path}: cannot parse: {err}", "fix the TOML/JSON syntax") from None
    for obj in data.get("objects", []) if isinstance(data, dict) else []:
        if isinstance(obj, dict) and isinstance(obj.get("mesh"), str):  # absolute: the spec (and a dataset's
            obj["mesh"] = str((path.parent / obj["mesh"]).absolute())  # meta.json) must not depend on the cwd
    return SceneSpec.from_dict(data, source=str(path))
