"""Request and response models of the HTTP API (pydantic only; the routers attach them to FastAPI).

Every field is bounded and finite (``allow_inf_nan=False``; JSON's ``NaN``/``Infinity`` and overflowing
literals such as ``1e999`` are rejected), of its JSON type without coercion (strict: ``"spp": "4"`` and
``"resolution": true`` are refused, an integer serves for a float), unknown fields are refused, so a bad request
is a 422 whose ``detail[].loc`` names the field. Bounds that depend on the server's settings (served
resolutions, the spp limit) and on the scene (its light range) are checked by the service with the same error
shape.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from baseline_cloudbaking.bake import SCENE_NAME
from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC, CodecName
from gicore.camera import Camera
from gicore.options import RESOLUTION_MAX, RESOLUTION_MIN, SPP_MAX

#: Largest |coordinate| of a camera or light position: far beyond any scene, small enough that the
#: camera matrices stay finite.
MAX_COORD = 1e4
Coord = Annotated[float, Field(ge=-MAX_COORD, le=MAX_COORD, strict=True)]
Vec3 = tuple[Coord, Coord, Coord]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class GICameraIn(_Strict):
    """The GI camera: a look-at pinhole (eye, target, up) with a horizontal FOV in degrees."""

    eye: Vec3 = Field(description="camera position, scene units")
    target: Vec3 = Field(description="point looked at")
    up: Vec3 = Field((0.0, 1.0, 0.0), description="up vector (not parallel to target - eye)")
    fov: float = Field(90.0, ge=1.0, le=170.0, strict=True, description="horizontal field of view, degrees (paper: 90)")

    @model_validator(mode="after")
    def _not_degenerate(self) -> GICameraIn:
        Camera(self.eye, self.target, self.up, fov=self.fov)  # ValueError names camera.origin/target/up
        return self


class GIMapRequest(_Strict):
    """Ask for the GI map at a GI camera."""

    scene: str = Field(
        pattern=SCENE_NAME.pattern, description="scene name (see GET /v1/scenes)", examples=["lung_plane"]
    )
    camera: GICameraIn
    light: Vec3 | None = Field(
        None,
        description="light position within the scene's light range (GET /v1/scenes: light_min to light_max, "
        "± light_cell); omit for the scene's rest position (a static light must be omitted)",
    )
    resolution: int = Field(
        256,
        ge=RESOLUTION_MIN,
        le=RESOLUTION_MAX,
        strict=True,
        description="square map size; one of the server's resolutions (GET /v1/scenes); omitted: the server's default",
    )
    codec: CodecName = Field(DEFAULT_CODEC, description=f"GI-map codec, one of {', '.join(CODEC_NAMES)}")
    spp: int = Field(
        64,
        ge=1,
        le=SPP_MAX,
        strict=True,
        description="path-tracing samples per pixel (bounded by the server's max_spp); omitted: the server's default",
    )
    di: bool = Field(
        False, strict=True, description="also send the DI of the GI view (the residual composition needs it)"
    )


class Health(BaseModel):
    status: Literal["ok"] = "ok"
    version: str
    store: str = Field(description="the GI tree's folder name (no path: responses reveal no file-system layout)")


class SceneInfo(BaseModel):
    """A scene's ranges: where its light moves and where its camera path goes."""

    name: str
    environment: str
    light_moves: bool
    light_rest: tuple[float, float, float]
    light_min: tuple[float, float, float]
    light_max: tuple[float, float, float]
    light_cell: float | None = Field(
        description="light-cell side of GI-tree keys, and how far beyond light_min/light_max a requested light "
        "may be; null for a static light (no light level)"
    )
    camera_target: tuple[float, float, float]
    camera_radius: tuple[float, float]
    camera_height: tuple[float, float]
    camera_azimuth_deg: tuple[float, float]
    local_fov: float
    gi_fov: float
    near: float
    far: float


class ScenesOut(BaseModel):
    scenes: list[SceneInfo]
    invalid: dict[str, str] = Field(description="spec files of the scenes folder that fail validation, with the reason")
    resolutions: list[int]
    codecs: list[str]
    max_spp: int
    tolerance_position: float
    tolerance_angle_deg: float
