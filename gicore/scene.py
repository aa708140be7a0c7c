"""Scene specifications: validated plain data (TOML or JSON) describing one scene (SPEC §2).

A spec names its objects (procedural anatomy or a user mesh), the environment (a white ground plane,
a Cornell box, or nothing), one light and the camera fly-through. Built-in specs for the paper's five
scenes live in ``gicore/scenes/*.toml`` and load by name::

    spec = load_scene("lung_plane")            # built-in
    spec = load_scene("my_scene.toml")         # a file
    spec = SceneSpec.from_dict({...})          # plain dict

Invalid specs raise :class:`SceneSpecError` naming each offending field.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from gicore.anatomy import ANATOMY_KINDS

BUILTIN_DIR = Path(__file__).parent / "scenes"
Vec3 = tuple[float, float, float]
Unit = Annotated[float, Field(ge=0.0, le=1.0)]


class SceneSpecError(ValueError):
    """A scene spec failed validation; the message lists every bad field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ObjectSpec(_Strict):
    """One object: procedural ``anatomy`` (with seed and detail) or a user ``mesh`` file (OBJ/PLY/STL).

    The mesh is normalised to ``height`` scene units resting on y = 0, rotated about y by
    ``rotate_y`` degrees and moved by ``position``. The material is diffuse ``albedo`` plus a mild
    glossy lobe (rough dielectric coating with GGX ``roughness``).
    """

    name: str = Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")
    anatomy: Literal["lung", "digestive", "vessels"] | None = None
    mesh: Path | None = None
    seed: int = 0
    detail: float = Field(1.0, gt=0.0, le=4.0)
    height: float = Field(1.0, gt=0.0)
    position: Vec3 = (0.0, 0.0, 0.0)
    rotate_y: float = 0.0
    albedo: tuple[Unit, Unit, Unit] = (0.8, 0.35, 0.3)
    roughness: float = Field(0.35, gt=0.0, le=1.0)

    @model_validator(mode="after")
    def _one_source(self) -> "ObjectSpec":
        if (self.anatomy is None) == (self.mesh is None):
            raise ValueError("give exactly one of 'anatomy' (one of %s) or 'mesh' (a file path)" % (ANATOMY_KINDS,))
        return self


class LightSpec(_Strict):
    """A point light (``size`` = 0) or a small square area light facing down (``size`` > 0).

    ``position`` is the light's rest position; ``amplitude`` (x, y) and ``period`` (frames) make it move
    along x and y as ``position + amplitude * sin(2 pi frame / period)`` (paper IV.C). Zero amplitude
    means a static light: then no light schedule enters datasets or cache keys.
    """

    position: Vec3
    intensity: float = Field(gt=0.0)
    size: float = Field(0.0, ge=0.0)
    amplitude: tuple[float, float] = (0.0, 0.0)
    period: tuple[float, float] = (200.0, 300.0)

    @field_validator("period")
    @classmethod
    def _positive_period(cls, v: tuple[float, float]) -> tuple[float, float]:
        if min(v) <= 0:
            raise ValueError("periods must be > 0 frames")
        return v

    @property
    def moves(self) -> bool:
        return any(a != 0.0 for a in self.amplitude)


class CameraPathSpec(_Strict):
    """A smooth fly-through around ``target``: an orbit of ``radius`` at ``height`` that sweeps
    ``azimuth_range`` degrees (centred on ``azimuth_center``), with slow seeded wobble of radius and
    height. ``local_fov`` is the client's render camera, ``gi_fov`` the GI camera (paper: 60° and 90°).
    """

    target: Vec3 = (0.0, 0.5, 0.0)
    radius: float = Field(2.4, gt=0.0)
    height: float = 1.2
    azimuth_center: float = 0.0
    azimuth_range: float = Field(360.0, gt=0.0, le=360.0)
    wobble: float = Field(0.15, ge=0.0, lt=1.0)
    local_fov: float = Field(60.0, gt=0.0, lt=180.0)
    gi_fov: float = Field(90.0, gt=0.0, lt=180.0)
    near: float = Field(0.01, gt=0.0)
    far: float = Field(100.0, gt=0.0)

    @model_validator(mode="after")
    def _near_far(self) -> "CameraPathSpec":
        if self.far <= self.near:
            raise ValueError(f"far ({self.far}) must exceed near ({self.near})")
        return self


class SceneSpec(_Strict):
    """A whole scene; see the module docstring."""

    name: str
    objects: list[ObjectSpec] = Field(min_length=1)
    environment: Literal["white_plane", "cornell_box", "none"] = "white_plane"
    light: LightSpec
    camera: CameraPathSpec = CameraPathSpec()
    resolution: int = Field(256, ge=8, le=2048)

    @model_validator(mode="after")
    def _unique_names(self) -> "SceneSpec":
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise ValueError(f"object names must be unique, got {names}")
        return self

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "scene spec") -> "SceneSpec":
        try:
            return cls.model_validate(data)
        except ValidationError as err:
            lines = [f"{source}: {len(err.errors())} invalid field(s)"]
            for e in err.errors():
                where = ".".join(str(p) for p in e["loc"]) or "(top level)"
                lines.append(f"  {where}: {e['msg']}")
            raise SceneSpecError("\n".join(lines)) from None

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json")


def builtin_scenes() -> list[str]:
    """Names of the shipped scene specs (the paper's five scenes)."""
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.toml"))


def load_scene(name_or_path: str | Path) -> SceneSpec:
    """Load a built-in scene by name, or a ``.toml``/``.json`` file; relative mesh paths resolve
    against the spec file's folder."""
    path = Path(name_or_path)
    if not path.suffix and (BUILTIN_DIR / f"{path}.toml").is_file():
        path = BUILTIN_DIR / f"{path}.toml"
    if not path.is_file():
        raise FileNotFoundError(f"no scene spec {name_or_path!r}: not a file and not one of the built-in scenes {builtin_scenes()}")
    text = path.read_text()
    try:
        data = tomllib.loads(text) if path.suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as err:
        raise SceneSpecError(f"{path}: cannot parse: {err}") from None
    for obj in data.get("objects", []) if isinstance(data, dict) else []:
        if isinstance(obj, dict) and "mesh" in obj and not Path(obj["mesh"]).is_absolute():
            obj["mesh"] = str(path.parent / obj["mesh"])
    return SceneSpec.from_dict(data, source=str(path))
