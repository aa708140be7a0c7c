"""Pinhole cameras and their OpenGL-convention matrices (docs/architecture.md, Cameras and matrices).

A :class:`Camera` is a look-at pinhole with a horizontal field of view. Mitsuba's ``to_world`` maps camera
space (+x left, +y up, +z forward) to world space; the OpenGL matrices used by warping are::

    view = diag(-1, 1, -1, 1) @ inverse(to_world)        # camera looks down -z, +x right
    proj = GL perspective, fx = 1 / tan(fov_x / 2), fy = fx * width / height
    uv   = clip.xy / (2 * clip.w) + 0.5                  # v grows bottom-up
    pixel column = u * width, pixel row = (1 - v) * height  (row 0 at the top, as in images)

A world point seen at pixel (row, col) of a render projects back within half a pixel of that pixel's
centre (tested).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from gicore.config import strict_from_dict
from gicore.error_policy import RESOLUTION_MAX, RESOLUTION_MIN

GL_FROM_MITSUBA = np.diag([-1.0, 1.0, -1.0, 1.0])
#: Clip distances the renderer represents, with a wide margin. Measured with Mitsuba 3.9 (llvm_ad_rgb) on a
#: 32² scene against near 0.01 / far 100: DI and G-buffers match to 1e-6 for near down to 1e-17 and far up
#: to 3e38 (float32's largest); near 1e-18 shifts DI by 1e-3, near 1e-19 or far 1e39 render black frames.
NEAR_MIN, FAR_MAX = 1e-10, 1e30
#: Largest coordinate of an origin or target: what the renderer represents (float32), with FAR_MAX's margin.
COORD_MAX = FAR_MAX
#: Narrowest field of view, degrees: far narrower than any lens, its focal factor 1 / tan(fov / 2) (1.1e8) well
#: within float32 and the level-of-detail model (1e-300 overflowed both).
FOV_MIN = 1e-6


def _vec3(name: str, value: Any) -> tuple[float, float, float]:
    """``value`` as three finite floats (plain Python: the server checks a camera per request, and numpy's
    per-call cost was most of that check)."""
    try:
        if isinstance(value, (str, bytes)) or len(value) != 3:
            raise TypeError
        components = [float(c) for c in value]
    except (TypeError, ValueError):
        raise ValueError(f"camera.{name} must have 3 components, got {value!r}") from None
    except OverflowError:
        components = [math.inf]
    if not all(math.isfinite(c) for c in components):
        raise ValueError(f"camera.{name} must be finite, got {value!r}")
    x, y, z = components
    return (x, y, z)


def _norm(v: tuple[float, float, float]) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


@dataclass(frozen=True)
class Camera:
    """A look-at pinhole camera.

    ``fov`` is the horizontal field of view in degrees, at least :data:`FOV_MIN` and below 180. ``near``/``far`` are
    clip distances (only the GL projection and Mitsuba's clipping use them), within
    [:data:`NEAR_MIN`, :data:`FAR_MAX`]. ``up`` need not be
    orthogonal to the view direction but must not be parallel to it.
    """

    origin: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 60.0
    near: float = 0.01
    far: float = 100.0
    width: int = 256
    height: int = 256

    def __post_init__(self) -> None:
        for name in ("origin", "target", "up"):
            object.__setattr__(self, name, _vec3(name, getattr(self, name)))
        for name in ("fov", "near", "far"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"camera.{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if not FOV_MIN <= self.fov < 180.0:
            raise ValueError(f"camera.fov must be at least {FOV_MIN:g} and below 180 degrees, got {self.fov}")
        if not NEAR_MIN <= self.near < self.far <= FAR_MAX:
            raise ValueError(
                f"camera.near/far must satisfy {NEAR_MIN:g} <= near < far <= {FAR_MAX:g} "
                f"(what the renderer represents), got near={self.near}, far={self.far}"
            )
        for name in ("width", "height"):
            value = getattr(self, name)
            try:
                ok = float(value).is_integer() and RESOLUTION_MIN <= int(value) <= RESOLUTION_MAX
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise ValueError(
                    f"camera.{name} must be an integer in [{RESOLUTION_MIN}, {RESOLUTION_MAX}], got {value}"
                )
            object.__setattr__(self, name, int(value))
        self._check_look_at()

    def _check_look_at(self) -> None:
        """The origin and target within reach, apart, and an up that is a direction off the view's."""
        for name in ("origin", "target"):
            point = getattr(self, name)
            if max(abs(c) for c in point) > COORD_MAX:
                raise ValueError(
                    f"camera.{name} {list(point)} lies beyond ±{COORD_MAX:g} (what the renderer represents)"
                )
        d = tuple(t - o for t, o in zip(self.target, self.origin))
        length = _norm(d)
        if length < 1e-9:
            raise ValueError("camera.origin and camera.target coincide; the view direction is undefined")
        up_length = _norm(self.up)
        if up_length < 1e-12:  # a direction takes a length; (0, 0, 0) is none
            raise ValueError(f"camera.up {list(self.up)} has no length; give the screen's up, e.g. [0, 1, 0]")
        (a, b, c), (u, v, w) = (x / length for x in d), (x / up_length for x in self.up)
        if _norm((b * w - c * v, c * u - a * w, a * v - b * u)) < 1e-6:
            raise ValueError(
                f"camera.up {self.up} is parallel to the view direction (degenerate look-at); pick another up"
            )

    # -- matrices -------------------------------------------------------------------------------
    def to_world(self) -> np.ndarray:
        """Mitsuba's look-at camera-to-world matrix (+x left, +y up, +z forward)."""
        o = np.asarray(self.origin)
        d = np.subtract(self.target, o)
        d /= np.linalg.norm(d)
        left = np.cross(self.up, d)
        left /= np.linalg.norm(left)
        new_up = np.cross(d, left)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
        return m

    def view(self) -> np.ndarray:
        """OpenGL view matrix: world to eye space, camera looking down -z."""
        return GL_FROM_MITSUBA @ np.linalg.inv(self.to_world())

    def proj(self) -> np.ndarray:
        """OpenGL perspective projection (clip space, depth mapped to [-1, 1])."""
        fx = 1.0 / math.tan(math.radians(self.fov) / 2.0)
        fy = fx * self.width / self.height
        n, f = self.near, self.far
        return np.array(
            [
                [fx, 0.0, 0.0, 0.0],
                [0.0, fy, 0.0, 0.0],
                [0.0, 0.0, -(f + n) / (f - n), -2.0 * f * n / (f - n)],
                [0.0, 0.0, -1.0, 0.0],
            ]
        )

    def view_proj(self) -> np.ndarray:
        return self.proj() @ self.view()

    # -- projections ----------------------------------------------------------------------------
    def view_depth(self, points: np.ndarray) -> np.ndarray:
        """Linear view depth (distance along the viewing axis) of world points (..., 3)."""
        v = self.view()
        return -(np.asarray(points) @ v[2, :3] + v[2, 3])

    def project_uv(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) to texture coordinates uv (..., 2) (eq. 5) and clip w (...,).

        uv is only meaningful where ``w > 0`` (in front of the camera); elsewhere it is NaN-free but
        undefined, so callers must mask with ``w > 0``.
        """
        p = np.asarray(points, dtype=np.float64)
        clip = p @ self.view_proj()[:, :3].T + self.view_proj()[:, 3]
        w = clip[..., 3]
        safe_w = np.where(np.abs(w) > 1e-12, w, 1e-12)
        uv = clip[..., :2] / (2.0 * safe_w[..., None]) + 0.5
        return uv, w

    def project_pixels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points to continuous pixel coordinates (col, row) with pixel centres at +0.5; and w."""
        uv, w = self.project_uv(points)
        cols = uv[..., 0] * self.width
        rows = (1.0 - uv[..., 1]) * self.height
        return np.stack([cols, rows], axis=-1), w

    # -- conveniences ---------------------------------------------------------------------------
    def with_fov(self, fov: float) -> Camera:
        return replace(self, fov=fov)

    def turned(self, degrees: float) -> Camera:
        """This camera turned about the vertical axis through its origin (positive: to the left)."""
        c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
        yaw = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        return replace(self, target=tuple(np.add(self.origin, yaw @ np.subtract(self.target, self.origin))))

    def moved(self, right: float = 0.0, back: float = 0.0) -> Camera:
        """This camera moved ``right`` units along its right vector and ``back`` units against its view
        direction, looking the same way."""
        m = self.to_world()
        shift = -right * m[:3, 0] - back * m[:3, 2]  # Mitsuba's camera x points left, z forward
        return replace(self, origin=tuple(np.add(self.origin, shift)), target=tuple(np.add(self.target, shift)))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Camera:
        return strict_from_dict(cls, d, "camera")
