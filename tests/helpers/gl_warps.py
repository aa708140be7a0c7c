"""What the tests of the warps' GL backends share: a lung_plane GI map rendered on the GL renderer, a source
that serves it, and the comparison of a GL warp's output with the numpy warp's.

The map is the GL DI at the GI camera plus a stand-in indirect term (0.3 x albedo): it has the scene's edges,
shadows and background, which is all a warp sees of a map (a path-traced map would only cost time here).
"""

from __future__ import annotations

import numpy as np

from gicore.camera import Camera
from gicore.gi_map import GIMap, texel_depth
from gicore.loop import ClientLoop, FrameResult, LoopConfig, SynchronousSource

#: Square resolution of the comparisons: small, and not a power of two (odd push-pull levels, non-dyadic texels).
RES = 48
#: A difference of float32 rounding alone: a few ulps of the values warped (<= 1).
ULPS = 1e-5
#: GI-camera FOV and local FOV (the clients' defaults: the local view magnifies the map 1.7x).
GI_FOV, LOCAL_FOV = 90.0, 60.0


def lung_scene() -> tuple:
    """(GL renderer of lung_plane at :data:`RES`, the fly-through's cameras, the light, a map at the first
    camera with the GI FOV: see the module docstring)."""
    from gicore.gl import GLRenderer
    from gicore.paths import camera_path, light_position
    from gicore.scene import load_scene

    spec = load_scene("lung_plane")
    gl = GLRenderer(spec, RES)
    cams = camera_path(spec, 300, seed=0, fov=LOCAL_FOV, resolution=RES)
    light = light_position(spec, 0)
    camera = cams[0].with_fov(GI_FOV)
    buffers = gl.render_di_gbuffers(camera, light)
    di = buffers["di"]
    return gl, cams, light, GIMap(camera, di + 0.3 * buffers["albedo"], texel_depth(gl, camera), di)


def loop_frames(scene: tuple, warp, composition: str) -> list[FrameResult]:
    """Frames 0, 4, ... 20 of a client loop on ``scene`` (:func:`lung_scene`) with ``warp``, its map bound anew
    every 3 frames."""
    gl, cams, light, gi = scene
    loop = ClientLoop(LoopConfig(every=3, gi_fov=GI_FOV, composition=composition, tau=0.3), gl, StaticSource(gi), warp)
    loop.warm_up(cams[0], light)  # binds a blank map: no point, no surface
    return [loop.step(f, cams[f], light) for f in range(0, 24, 4)]


class StaticSource(SynchronousSource):
    """Serves one map on every request (a client loop without a model or a server)."""

    name = "static"

    def __init__(self, gi: GIMap):
        super().__init__()
        self.gi = gi

    def produce(self, camera: Camera, light, frame: int) -> GIMap:
        return self.gi


def differences(gl: tuple[np.ndarray, np.ndarray], host: tuple[np.ndarray, np.ndarray]) -> dict[str, float]:
    """Of two (image, valid) outputs: mean and max |gl - numpy|, the share of pixels that differ by more than
    :data:`ULPS` and the share whose valid masks differ."""
    diff = np.abs(gl[0].astype(np.float64) - host[0]).max(axis=-1)
    return {
        "mean_abs": float(diff.mean()),
        "max_abs": float(diff.max()),
        "differ": float(np.mean(diff > ULPS)),
        "valid_differs": float(np.mean(gl[1] != host[1])),
    }


def contrast(image: np.ndarray, reach: int = 2) -> float:
    """The largest |difference| between two texels of ``image`` at most ``reach`` texels apart along x and y."""
    h, w = image.shape[:2]
    padded = np.pad(image, ((reach, reach), (reach, reach), (0, 0)), mode="edge")
    shifts = [padded[reach + dy : reach + dy + h, reach + dx : reach + dx + w] for dy in range(-reach, reach + 1)
              for dx in range(-reach, reach + 1)]  # fmt: skip
    return float(np.max([np.abs(s - image).max() for s in shifts]))
