"""The GI map: the value a GI source makes and a warp brings to other views (docs/architecture.md, Client
loop), and the depth it carries.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from gicore.camera import Camera
from gicore.tonemap import linear_of_display

if TYPE_CHECKING:
    from gicore.render import Renderer

#: Stage name to milliseconds, as sources, warps and the loop report them.
Timings = dict[str, float]
#: What a warp brings to the current view, per composition: the full GI map for eq. 1, its indirect
#: part for the residual composition (which adds it to the current DI).
LAYERS = {"blend": "radiance", "residual": "indirect"}


@dataclass(frozen=True, eq=False)
class GIMap:
    """A GI map at its GI ``camera`` (whose ``view()``/``proj()`` are the OpenGL matrices the warps use),
    with what warping and composition need, and when it was asked for and arrived.

    ``linear``: linear GI, HxWxC (C = 3 for real maps), or None when the map arrived as ``display`` only: its
    8-bit tone-mapped values (HxWx3 uint8, as an 8-bit codec carries them), which a GL warp uploads and decodes
    on the GPU; :attr:`radiance` is the linear GI either way (from ``display`` on first use). ``depth``: linear
    view depth at texel centres, HxW, 0 = background; ``di``: the direct illumination the map was made with at
    the same camera (HxWxC), or None when the source did not send it (then :attr:`indirect` is unavailable);
    ``frame``: the frame that requested it; ``requested_at`` / ``arrived_at``: ``time.perf_counter()``
    stamps; ``stages``: what producing it cost, ms per stage (the source's :attr:`GISource.stages`).
    """

    camera: Camera
    linear: np.ndarray | None
    depth: np.ndarray
    di: np.ndarray | None = None
    frame: int = -1
    requested_at: float = 0.0
    arrived_at: float = 0.0
    stages: Timings = field(default_factory=dict)
    display: np.ndarray | None = None

    def __post_init__(self) -> None:
        shape = (self.camera.height, self.camera.width)
        image = self.linear if self.linear is not None else self.display
        if image is None:
            raise ValueError("a GI map needs its linear GI or its 8-bit display values")
        if self.display is not None and (self.display.dtype != np.uint8 or self.display.shape[2:] != (3,)):
            raise ValueError(
                f"a GI map's display values are HxWx3 uint8, got {self.display.dtype} {self.display.shape}"
            )
        if image.ndim != 3 or image.shape[:2] != shape or self.depth.shape != shape:
            raise ValueError(
                f"GI map {image.shape} and depth {self.depth.shape} must be {shape[0]}x{shape[1]}(xC)"
                " like the GI camera"
            )
        if self.di is not None and self.di.shape != image.shape:
            raise ValueError(f"the GI map's DI is {self.di.shape}, its radiance {image.shape}")

    @cached_property
    def radiance(self) -> np.ndarray:
        """The linear GI, HxWxC: ``linear``, or ``display`` decoded (computed once, on first use)."""
        return self.linear if self.linear is not None else linear_of_display(self.display)

    @cached_property
    def indirect(self) -> np.ndarray:
        """The map's indirect light ``max(radiance - di, 0)`` (computed once, on first use)."""
        if self.di is None:
            raise ValueError(
                "this GI map carries no DI of its view, so its indirect part is unknown; ask the source for the DI too"
            )
        return np.maximum(self.radiance - self.di, 0.0)

    def layer(self, name: str) -> np.ndarray:
        """``"radiance"`` or ``"indirect"`` (see :data:`LAYERS`)."""
        if name not in ("radiance", "indirect"):
            raise ValueError(f"layer must be 'radiance' or 'indirect', got {name!r}")
        return self.radiance if name == "radiance" else self.indirect

    @property
    def latency_ms(self) -> float:
        """Request to arrival."""
        return (self.arrived_at - self.requested_at) * 1e3

    @classmethod
    def blank(cls, camera: Camera, channels: int = 3) -> GIMap:
        """An all-background map (zero radiance and depth): binds and warps like any map, so it warms up a
        warp's passes without a source."""
        zeros = np.zeros((camera.height, camera.width, channels), np.float32)
        return cls(camera, zeros, np.zeros(zeros.shape[:2], np.float32), zeros)


def texel_depth(renderer: Renderer, camera: Camera) -> np.ndarray:
    """A GI map's depth: linear view depth at texel centres from the centre-sampled pass (0 on background),
    so that warps unproject exact centre rays and a map warped to its own camera is the identity."""
    p = renderer.render_uv(camera)
    return np.where(p["mask"], camera.view_depth(p["position"]), 0.0).astype(np.float32)
