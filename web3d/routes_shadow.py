"""``GET /v1/shadow?light=x,y,z``: the shadow-map setup the page needs for a light where the user put it.

It is :func:`web3d.export.shadow_setup` for the served scene (the views :class:`~gicore.gl.GLRenderer` fits
around the casters for that light: column-major matrices, texel sizes, the atlas layout), so the page shadows
exactly as the Python clients do. The light must lie in the box the cloud-baking server accepts
(:func:`gicore.paths.light_bounds`: the light's sweep widened by one light cell; a static light's rest
point); elsewhere, or not three finite numbers: 422.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import JSONResponse

from gicore.geometry import scene_objects
from gicore.gl.shadow import object_bounds
from gicore.paths import light_bounds
from gicore.scene import SceneSpec
from web3d.export import shadow_setup

router = APIRouter()
#: Slack on the light box's faces (a light the page clamped onto a face, after a round trip through text).
_SLACK = 1e-9


class Shadows:
    """The shadow-map setups of one scene, for maps ``size`` texels a side."""

    def __init__(self, spec: SceneSpec, size: int) -> None:
        self.bounds = object_bounds(scene_objects(spec), len(spec.objects))
        self.box = light_bounds(spec)
        self.size = size

    def setup(self, light: tuple[float, float, float]) -> dict[str, Any]:
        """The setup for a light at ``light``; ValueError naming the box when it lies outside."""
        low, high = self.box
        if not all(lo - _SLACK <= c <= hi + _SLACK for c, lo, hi in zip(light, low, high)):
            raise ValueError(f"light {list(light)} lies outside the scene's light range {[list(low), list(high)]}")
        return shadow_setup(self.bounds, np.asarray(light, dtype=np.float64), self.size)


def parse_light(text: str) -> tuple[float, float, float]:
    """``x,y,z`` as three finite numbers; ValueError otherwise."""
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"light={text!r} is not three finite numbers x,y,z")
    return values  # type: ignore[return-value]


@router.api_route("/v1/shadow", methods=["GET", "HEAD"], include_in_schema=False)
async def shadow(request: Request, light: str = "") -> JSONResponse:
    shadows: Shadows | None = request.app.state.site.shadows
    if shadows is None:
        raise HTTPException(404, "no scene is served here")
    try:
        setup = shadows.setup(parse_light(light))
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    return JSONResponse(setup)
