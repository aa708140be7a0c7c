"""When the cloud-baking client asks for a GI map (docs/architecture.md, Request policy and prefetch): only
when no map it holds or has in flight serves the view by the GI tree's rule (:func:`covers`), and, with
prefetch, for the view its recent motion reaches one request latency ahead (:class:`MotionPredictor`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from baseline_cloudbaking.viewpoints import Tolerance, Viewpoint, light_cell, nearest
from gicore.camera import Camera
from gicore.paths import Light

#: Prefetch policies (:attr:`baseline_cloudbaking.client_run.CloudClientConfig.prefetch`).
PREFETCH = ("none", "extrapolate")
#: Request rules (:attr:`baseline_cloudbaking.client_run.CloudClientConfig.hold`).
HOLDS = ("tolerance", "none")
#: A light cell of the GI tree's keys (None: a static light, no light level).
LightCell = tuple[int, int, int] | None


@dataclass(frozen=True)
class RequestPolicy:
    """When a :class:`baseline_cloudbaking.client.RemoteSource` sends the requests the loop asks for (module
    docstring)."""

    #: The server's tolerance; None: send whenever asked and free (the loop's period k and its own test decide).
    tolerance: Tolerance | None = None
    #: The server's light-cell side for the scene (None: a static light, no light level in the tree's keys).
    light_cell: float | None = None
    #: ``none`` or ``extrapolate`` (needs ``tolerance``).
    prefetch: str = "none"
    #: Recent frames whose motion is extrapolated.
    history: int = 8
    #: Recent requests whose median latency sets the prefetch lead.
    latencies: int = 8
    #: Requests in flight at most (each on its own connection); with prefetch, successive views ahead.
    in_flight: int = 1

    def __post_init__(self) -> None:
        if self.prefetch not in PREFETCH:
            raise ValueError(f"prefetch must be one of {PREFETCH}, got {self.prefetch!r}")
        if self.prefetch != "none" and self.tolerance is None:
            raise ValueError("prefetch needs the server's tolerance (a map is asked ahead only when none held serves)")
        if self.history < 2 or self.latencies < 1 or self.in_flight < 1:
            raise ValueError(
                f"history must be >= 2, latencies and in_flight >= 1, got {self.history}, {self.latencies} and"
                f" {self.in_flight}"
            )

    def cell(self, light: Light) -> LightCell:
        return light_cell(light, self.light_cell)


def covers(map_camera: Camera, map_cell: LightCell, camera: Camera, cell: LightCell, tol: Tolerance) -> bool:
    """Whether a map at ``map_camera`` (made in light cell ``map_cell``) serves a request at ``camera`` in light
    cell ``cell``: the GI tree's own lookup rule (:func:`baseline_cloudbaking.viewpoints.nearest`)."""
    if map_cell != cell:
        return False
    held = viewpoint_of(map_camera)
    return nearest(np.array([held.eye]), np.array([held.direction]), viewpoint_of(camera), tol) is not None


def viewpoint_of(camera: Camera) -> Viewpoint:
    """The GI tree's viewpoint of ``camera``: its eye and unit view direction."""
    return Viewpoint.look_at(camera.origin, camera.target)


class MotionPredictor:
    """The recent motion of the camera and the light (the last ``history`` views: frame, when it was asked for,
    camera, light), extrapolated: eye position, view direction and light position fitted against the frame number
    by least squares (a parabola from five views on, as an orbit bends; a line before), evaluated the frames ahead
    that a lead in seconds spans at the median frame interval. Fitting against frames, not request times, keeps
    the jitter of when in its frame a view was asked for out of the motion; the direction is renormalised. The
    light is predicted too: a map asked ahead under the current light would miss the maps baked past a light-cell
    boundary."""

    def __init__(self, history: int):
        self._views: deque[tuple[int, float, np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=history)

    def add(self, frame: int, t: float, camera: Camera, light: Light) -> None:
        if self._views and frame <= self._views[-1][0]:  # a frame asked twice (or a restart): keep the motion
            return
        view = viewpoint_of(camera)
        self._views.append((frame, t, np.array(view.eye), np.array(view.direction), np.array(light, dtype=float)))

    def frame_interval_s(self) -> float | None:
        """Median time per frame between the views (None before two)."""
        if len(self._views) < 2:
            return None
        frames = np.diff([v[0] for v in self._views])
        return float(np.median(np.diff([v[1] for v in self._views]) / frames))

    def crossing_s(self, tol: Tolerance) -> float | None:
        """Time the camera takes to move one tolerance (its eye ``tol.position`` or its direction ``tol.angle_deg``,
        whichever comes first) at its last speed; None before two views or when it stands still."""
        interval = self.frame_interval_s()
        if interval is None:
            return None
        (f0, _, e0, d0, _), (f1, _, e1, d1, _) = self._views[-2], self._views[-1]
        move = float(np.linalg.norm(e1 - e0)) / max(tol.position, 1e-12)
        turn = math.degrees(math.atan2(float(np.linalg.norm(np.cross(d0, d1))), float(d0 @ d1)))
        per_frame = max(move, turn / max(tol.angle_deg, 1e-12)) / (f1 - f0)
        return interval / per_frame if per_frame > 0.0 else None

    def predict(self, camera: Camera, lead_s: float) -> tuple[Camera, Light] | None:
        """``camera`` moved to where its motion puts it ``lead_s`` after the last view (its distance to its
        target, its up and FOV kept), and the light then; None before three views."""
        interval = self.frame_interval_s()
        if len(self._views) < 3 or interval is None or not interval > 0.0:
            return None
        f = np.array([v[0] for v in self._views], dtype=float)
        f -= f[-1]
        ahead = lead_s / interval
        degree = 2 if len(f) >= 5 else 1
        eye, d, light = (
            np.array([np.polyval(np.polyfit(f, values[:, i], degree), ahead) for i in range(3)])
            for values in (np.array([v[k] for v in self._views]) for k in (2, 3, 4))
        )
        norm = float(np.linalg.norm(d))
        if not (np.isfinite(eye).all() and np.isfinite(light).all() and math.isfinite(norm) and norm > 1e-9):
            return None
        reach = float(np.linalg.norm(np.subtract(camera.target, camera.origin)))
        try:
            moved = replace(camera, origin=tuple(eye), target=tuple(eye + d / norm * reach))
        except ValueError:  # e.g. a view direction parallel to up: ask for the view as it is
            return None
        return moved, (float(light[0]), float(light[1]), float(light[2]))


#: The policy of a source told no other: send whenever the loop asks and a connection is free.
SEND_WHEN_ASKED = RequestPolicy()
