"""What a numerical-stability case is and what cases share: a :class:`Case` runs one stage on one extreme
input and expects ``finite`` or ``rejected`` (:class:`Outcome`, :class:`Rejected`); :class:`Scene` is the
scene the render, warp, inference and server cases work on; :func:`tm_rmse`, :func:`max_rel` and
:func:`with_nan` measure errors and spoil inputs.

Each package declares the extreme inputs its own stages must survive as Cases in its ``stability_cases``
module; ``bench stability`` judges, records and presents them (docs/architecture.md, Numerical stability).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

Expect = Literal["finite", "rejected"]


class Rejected(Exception):
    """A clean refusal that is not an exception of the stage itself: an HTTP 4xx naming the field, a
    client timeout, a link that never delivers."""


@dataclass(frozen=True)
class Outcome:
    """What a case that ran to the end produced: its outputs (checked finite) and, where a reference
    exists, its error against it and the bound that error must stay within."""

    outputs: tuple[Any, ...] = ()
    error: float | None = None
    #: What ``error`` measures (its unit column).
    error_kind: str = ""
    bound: float | None = None
    note: str = ""


@dataclass(frozen=True)
class Case:
    stage: str
    name: str
    expect: Expect
    run: Callable[[], Outcome]


def tm_rmse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """RMSE of the tone-mapped images (on ``mask`` pixels only when given)."""
    from gicore.tonemap import tonemap

    d = tonemap(a) - tonemap(b)
    d = d[mask] if mask is not None else d
    return float(np.sqrt(np.mean(d.astype(np.float64) ** 2))) if d.size else 0.0


def max_rel(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max(|b|, tiny): relative deviation of ``a`` from ``b``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    scale = np.maximum(np.abs(b), 1e-30)
    return float(np.max(np.abs(a - b) / scale)) if a.size else 0.0


def with_nan(x: np.ndarray, value: float = math.nan) -> np.ndarray:
    y = np.array(x, dtype=np.float32, copy=True)
    y.reshape(-1)[y.size // 2] = value
    return y


@dataclass
class Scene:
    """The scene's renderers, its reference view (local and GI camera, light) and a GI map there."""

    spec: Any
    renderer: Any
    local: Any
    gi_camera: Any
    light: tuple[float, float, float]
    spp: int
    seed: int
    _renderers: dict[float, Any] = field(default_factory=dict)

    @classmethod
    def load(cls, name: str, resolution: int, spp: int, seed: int) -> Scene:
        from gicore.paths import camera_path, light_position
        from gicore.render import Renderer
        from gicore.scene import load_scene

        spec = load_scene(name)
        local = camera_path(spec, 30, seed=seed, fov=spec.camera.local_fov, resolution=resolution)[0]
        return cls(
            spec,
            Renderer(spec, resolution),
            local,
            local.with_fov(spec.camera.gi_fov),
            light_position(spec, 0),
            spp,
            seed,
        )

    def scaled(self, factor: float) -> Any:
        """A renderer of the same scene with the light's intensity times ``factor``."""
        from gicore.render import Renderer

        if factor not in self._renderers:
            spec = self.spec.model_copy(
                update={"light": self.spec.light.model_copy(update={"intensity": self.spec.light.intensity * factor})}
            )
            self._renderers[factor] = Renderer(spec, self.renderer.resolution)
        return self._renderers[factor]

    def passes(self, camera, light=None, renderer=None) -> dict[str, np.ndarray]:
        """Every render pass at ``camera``: DI, centre-sampled G-buffers, path-traced GT, the warp raster."""
        r = renderer or self.renderer
        light = self.light if light is None else light
        out = r.render_di_gbuffers(camera, light, seed=self.seed, centre=True)
        out["gt"] = r.render_gt(camera, light, spp=self.spp, seed=self.seed)
        uv = r.render_uv(camera)
        return out | {"uv": uv["uv"], "position_uv": uv["position"]}

    def touching_light(self) -> tuple[float, float, float]:
        """A light 1e-4 in front of the surface point seen at the local camera's centre pixel (less than
        Mitsuba's ray-spawn offset, ~9e-5 x (1 + |p|)), towards the camera: visible, never occluded."""
        uv = self.renderer.render_uv(self.local)
        rows, cols = np.nonzero(uv["mask"])
        if rows.size == 0:
            raise RuntimeError("the reference view shows no surface")
        h, w = uv["mask"].shape
        i = int(np.argmin((rows - h / 2) ** 2 + (cols - w / 2) ** 2))
        p = uv["position"][rows[i], cols[i]].astype(np.float64)
        towards = np.subtract(self.local.origin, p)
        return tuple(map(float, p + 1e-4 * towards / np.linalg.norm(towards)))

    def gi_map(self, camera=None):
        """A GI map at ``camera`` (default: the GI camera): path-traced GI, its DI, texel depth."""
        from gicore.gi_map import GIMap, texel_depth

        camera = camera or self.gi_camera
        r = self.renderer
        return GIMap(
            camera,
            r.render_gt(camera, self.light, spp=self.spp, seed=self.seed),
            texel_depth(r, camera),
            r.render_di(camera, self.light),
        )
