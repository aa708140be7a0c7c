"""``GET /v1/scenes``: the scenes served, with their light and camera ranges, and the request bounds."""

from __future__ import annotations

from fastapi import APIRouter

from baseline_cloudbaking.codecs import CODEC_NAMES
from baseline_cloudbaking.server.deps import ServiceDep, SettingsDep
from baseline_cloudbaking.server.errors import public_roots, redact
from baseline_cloudbaking.server.schemas import SceneInfo, ScenesOut
from gicore.paths import light_range
from gicore.scene import SceneSpec, SceneSpecError

router = APIRouter(prefix="/v1", tags=["scenes"])


def scene_info(name: str, spec: SceneSpec, light_cell: float | None) -> SceneInfo:
    """Ranges of ``spec``: the light sweeps rest ± amplitude in x and y; the camera orbits ``target`` at a
    radius and height wobbling by ± ``wobble``, over the azimuth arc (the whole circle when 360°)."""
    light, cam = spec.light, spec.camera
    light_min, light_max = light_range(spec)
    if cam.azimuth_range >= 360.0:
        azimuth = (0.0, 360.0)
    else:
        azimuth = (cam.azimuth_center - cam.azimuth_range / 2, cam.azimuth_center + cam.azimuth_range / 2)
    return SceneInfo(
        name=name,
        environment=spec.environment,
        light_moves=light.moves,
        light_rest=light.position,
        light_min=light_min,
        light_max=light_max,
        light_cell=light_cell,
        camera_target=cam.target,
        camera_radius=(cam.radius * (1 - cam.wobble), cam.radius * (1 + cam.wobble)),
        camera_height=(cam.height * (1 - cam.wobble), cam.height * (1 + cam.wobble)),
        camera_azimuth_deg=azimuth,
        local_fov=cam.local_fov,
        gi_fov=cam.gi_fov,
        near=cam.near,
        far=cam.far,
    )


@router.get("/scenes", response_model=ScenesOut, summary="scenes, their light and camera ranges, request bounds")
def scenes(service: ServiceDep, settings: SettingsDep) -> ScenesOut:
    infos, invalid = [], {}
    for name in service.catalog.names():
        try:
            spec = service.catalog.get(name)
        except SceneSpecError as exc:
            invalid[name] = redact(str(exc), public_roots(settings))
            continue
        infos.append(scene_info(name, spec, service.light_cell_size(spec)))
    return ScenesOut(
        scenes=infos,
        invalid=invalid,
        resolutions=list(settings.resolutions),
        codecs=list(CODEC_NAMES),
        max_spp=settings.max_spp,
        tolerance_position=settings.tolerance_position,
        tolerance_angle_deg=settings.tolerance_angle_deg,
    )
