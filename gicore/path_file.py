"""Path files (``gigan-path/1``): a session's cameras and lights as data (docs/architecture.md, Path files).

A path file is JSON: ``{"format": "gigan-path/1", "scene": NAME, "frames": [{"t_ms", "camera": {"eye",
"target", "up", "fov", "near", "far"}, "light"}, ...], "source": TEXT}`` (``source`` optional). ``camera``
is the local camera (``fov``: :class:`gicore.camera.Camera`'s horizontal degrees); a frame's GI camera is
the same view at the scene's GI FOV. ``t_ms`` counts from the session's start and never decreases.

:func:`read_path_file` checks everything a run relies on against the scene spec, each failure one line
naming the file and the frame: the eye inside the scene's navigable envelope (:func:`gicore.paths.navigation`,
widened by :data:`NAVIGATION_MARGIN`), the light where the server serves it (:func:`gicore.paths.light_bounds`),
and the camera a valid one. The scripted fly-through is the same data (:func:`scripted_path`), so the
clients, the benches and the viewer fly recorded and scripted sessions alike.
"""

from __future__ import annotations

import json
import math
import os
import stat
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple, Protocol

from gicore.camera import Camera
from gicore.error_policy import UserError
from gicore.fileio import atomic_write_bytes
from gicore.options import FRAMES_MAX
from gicore.paths import Light, light_bounds, navigation, outside_navigation, path_views
from gicore.scene import SceneSpec

FORMAT = "gigan-path/1"
#: Largest path file read, bytes: FRAMES_MAX frames of about 400 bytes each, with room to spare.
PATH_BYTES_MAX = 64 << 20
#: Commas and brackets of a frame (16 and 6): a file with more than FRAMES_MAX frames' worth is refused unparsed,
#: since parsing makes every value first (30 MB of empty frames took 850 MB).
VALUES_PER_FRAME = 22
#: Commas and brackets besides the frames' (the top object's, any in its texts).
VALUES_SLACK = 4096
#: How far outside the navigable envelope an eye may be, as a fraction of the scene's orbit radius (what a
#: viewer's clamping and float rounding may leave).
NAVIGATION_MARGIN = 0.02
#: How far a static light may be from its rest point (the server's rule).
STATIC_LIGHT_SLACK = 1e-6
#: Frames per second the scripted fly-through's ``t_ms`` assume.
SCRIPTED_FPS = 30.0
_TOP_KEYS, _FRAME_KEYS = {"format", "scene", "frames", "source"}, {"t_ms", "camera", "light"}
_CAMERA_KEYS = {"eye", "target", "up", "fov", "near", "far"}
_TODO = "record the session again in gigan-web, or fix the file (format: docs/architecture.md, Path files)"


class Waypoint(NamedTuple):
    """One frame of a path: its time since the session's start, the local camera, the light position."""

    t_ms: float
    camera: Camera
    light: Light


@dataclass(frozen=True)
class PathFile:
    """A session's frames for scene ``scene``; ``source`` says where it came from (free text)."""

    scene: str
    frames: tuple[Waypoint, ...]
    source: str = ""

    def views(self, resolution: int, fov: float | None = None) -> list[tuple[Camera, Light]]:
        """(camera, light) of each frame at square ``resolution``: the local camera, or with ``fov`` the same
        view at that FOV (the GI camera). Cameras already at that resolution and FOV are returned as they are."""

        def camera(c: Camera) -> Camera:
            if (c.width, c.height) == (resolution, resolution) and fov in (None, c.fov):
                return c
            return replace(c, width=resolution, height=resolution, fov=c.fov if fov is None else fov)

        return [(camera(w.camera), w.light) for w in self.frames]

    def to_json(self) -> dict[str, Any]:
        """The file's JSON document."""
        frames = [
            {
                "t_ms": w.t_ms,
                "camera": {
                    "eye": list(w.camera.origin),
                    "target": list(w.camera.target),
                    "up": list(w.camera.up),
                    "fov": w.camera.fov,
                    "near": w.camera.near,
                    "far": w.camera.far,
                },
                "light": [float(v) for v in w.light],
            }
            for w in self.frames
        ]
        return {"format": FORMAT, "scene": self.scene, "frames": frames} | (
            {"source": self.source} if self.source else {}
        )


def write_path_file(path: Path, scene: str, views: Sequence[Waypoint], source: str = "") -> Path:
    """Write the frames ``views`` of ``scene`` as a path file, atomically."""
    doc = PathFile(scene, tuple(views), source).to_json()
    return atomic_write_bytes(Path(path), json.dumps(doc).encode())


def scripted_path(spec: SceneSpec, frames: int, orbit_frames: int, seed: int = 0, fov: float | None = None) -> PathFile:
    """The scene's fly-through (:func:`gicore.paths.path_views`: ``orbit_frames`` frames per lap from ``seed``,
    the light's schedule) as a path, local FOV ``fov`` (default: the scene's), ``t_ms`` at :data:`SCRIPTED_FPS`."""
    local = spec.camera.local_fov if fov is None else fov
    views = path_views(spec, frames, orbit_frames, seed, local, spec.resolution)
    points = tuple(Waypoint(f * 1000.0 / SCRIPTED_FPS, cam, light) for f, (cam, light) in enumerate(views))
    return PathFile(spec.name, points, f"scripted: seed {seed}, orbit {orbit_frames}")


class Flies(Protocol):
    """What :func:`flown_path` reads of a run's config: the path file, else the scripted path's shape."""

    path: Path | None
    frames: int
    orbit_frames: int


def flown_path(spec: SceneSpec, cfg: Flies, seed: int, fov: float | None = None) -> PathFile:
    """The path a run of ``cfg`` flies: its ``path`` file when given, else the scene's fly-through of
    ``frames`` frames (:func:`scripted_path` from ``seed`` at local FOV ``fov``)."""
    if cfg.path is not None:
        return read_path_file(cfg.path, spec)
    return scripted_path(spec, cfg.frames, cfg.orbit_frames, seed, fov)


# -- reading ------------------------------------------------------------------------------------------------
def _load(path: Path) -> Any:
    """The JSON document of ``path``, a regular file read up to :data:`PATH_BYTES_MAX` bytes and holding no more
    JSON values than :data:`FRAMES_MAX` frames do (:data:`VALUES_PER_FRAME`), both checked before it is parsed."""
    try:
        # non-blocking: a FIFO opens at once, without a writer, and is refused as no regular file
        with os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb") as fh:
            info = os.fstat(fh.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise UserError(f"path file {path} is not a regular file", "give a path file saved on disk")
            data = fh.read(min(info.st_size, PATH_BYTES_MAX) + 1)  # read(n) takes n bytes of memory first
    except OSError as err:
        raise UserError(f"path file {path}: cannot be read ({err.strerror or err})", "give an existing file") from None
    if len(data) > PATH_BYTES_MAX:
        raise UserError(f"path file {path} is over {PATH_BYTES_MAX >> 20} MiB", f"give at most {FRAMES_MAX} frames")
    # every value but a container's first follows a comma: commas and brackets bound the values parsing would make
    if data.count(b",") + data.count(b"[") + data.count(b"{") > VALUES_PER_FRAME * FRAMES_MAX + VALUES_SLACK:
        raise UserError(f"path file {path} holds more than {FRAMES_MAX} frames", f"give at most {FRAMES_MAX} frames")
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as err:  # ValueError: not JSON, not UTF-8, a number of over 4300 digits
        raise UserError(f"path file {path} is not JSON ({str(err).splitlines()[0][:80]})", _TODO) from None


def _keys(doc: Any, expected: set[str], optional: set[str], where: str) -> None:
    if not isinstance(doc, dict):
        raise ValueError(f"{where} is not a JSON object")
    missing, extra = expected - optional - doc.keys(), doc.keys() - expected
    if missing:
        raise ValueError(f"{where} lacks {', '.join(sorted(missing))}")
    if extra:
        raise ValueError(f"{where} has unknown key(s) {', '.join(sorted(map(str, extra)))[:80]}")


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where} is not a number: {json.dumps(value)[:40]}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise ValueError(f"{where} is not finite: {value!r:.40}")
    return number


def _vec3(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise ValueError(f"{where} is not a list of 3 numbers: {json.dumps(value)[:60]}")
    x, y, z = (_number(v, f"{where}[{i}]") for i, v in enumerate(value))
    return x, y, z


@dataclass(frozen=True)
class _Rules:
    """What every frame of a scene's path is checked against."""

    spec: SceneSpec
    navigation: dict[str, Any]
    margin: float
    light_low: Light
    light_high: Light
    light_slack: float

    @classmethod
    def of(cls, spec: SceneSpec) -> _Rules:
        slack = 0.0 if spec.light.moves else STATIC_LIGHT_SLACK
        return cls(spec, navigation(spec), NAVIGATION_MARGIN * spec.camera.radius, *light_bounds(spec), slack)


def _waypoint(doc: Any, rules: _Rules, previous_ms: float) -> Waypoint:
    """One frame, checked (ValueError saying what is wrong)."""
    _keys(doc, _FRAME_KEYS, set(), "the frame")
    _keys(doc["camera"], _CAMERA_KEYS, set(), "its camera")
    t_ms = _number(doc["t_ms"], "t_ms")
    if t_ms < previous_ms:
        raise ValueError(f"t_ms {t_ms:g} is before the previous frame's {previous_ms:g} (times never decrease)")
    cam = doc["camera"]
    eye, target, up = (_vec3(cam[k], f"camera.{k}") for k in ("eye", "target", "up"))
    fov, near, far = (_number(cam[k], f"camera.{k}") for k in ("fov", "near", "far"))
    try:
        camera = Camera(eye, target, up, fov, near, far, rules.spec.resolution, rules.spec.resolution)
    except ValueError as err:
        raise ValueError(str(err).replace("camera.origin", "camera.eye")) from None
    outside = outside_navigation(rules.navigation, eye, rules.margin)
    if outside:
        raise ValueError(f"camera.eye {list(eye)} is outside the scene's navigable envelope: {outside}")
    light = _vec3(doc["light"], "light")
    low, high, slack = rules.light_low, rules.light_high, rules.light_slack
    if not all(lo - slack <= v <= hi + slack for v, lo, hi in zip(light, low, high, strict=True)):
        box = " to ".join(str([round(c, 4) for c in corner]) for corner in (low, high))
        raise ValueError(f"light {list(light)} is outside the scene's light range {box}")
    return Waypoint(t_ms, camera, light)


def path_document(doc: Any, spec: SceneSpec, name: str) -> PathFile:
    """A path file's parsed JSON ``doc`` checked against ``spec`` (module docstring); ``name`` names it in errors."""
    try:
        _keys(doc, _TOP_KEYS, {"source"}, "the document")
    except ValueError as err:
        raise UserError(f"path file {name}: {err}", _TODO) from None
    if doc["format"] != FORMAT:
        raise UserError(f"path file {name}: format {json.dumps(doc['format'])[:40]} is not {FORMAT!r}", _TODO)
    if doc["scene"] != spec.name:
        raise UserError(
            f"path file {name} is for scene {doc['scene']!r:.60}, not {spec.name!r}",
            "fly it in the scene it was recorded in",
        )
    if not isinstance(doc.get("source", ""), str):
        raise UserError(f"path file {name}: source is not text", _TODO)
    frames = doc["frames"]
    if not isinstance(frames, list) or not 1 <= len(frames) <= FRAMES_MAX:
        count = f"{len(frames)} frames" if isinstance(frames, list) else "frames not a list"
        raise UserError(f"path file {name} has {count}", f"give 1 to {FRAMES_MAX} frames")
    points: list[Waypoint] = []
    rules = _Rules.of(spec)
    for i, frame in enumerate(frames):
        try:
            points.append(_waypoint(frame, rules, points[-1].t_ms if points else 0.0))
        except ValueError as err:
            raise UserError(f"path file {name}: frame {i}: {err}", _TODO) from None
    return PathFile(spec.name, tuple(points), doc.get("source", ""))


def read_path_file(path: Path, spec: SceneSpec) -> PathFile:
    """The path file at ``path``, checked against ``spec`` (module docstring); one-line UserErrors."""
    return path_document(_load(path), spec, str(path))


def read_sessions(folder: Path, specs: Sequence[SceneSpec]) -> dict[str, list[PathFile]]:
    """Every ``*.json`` path file in ``folder`` (name order), by the scene of ``specs`` it names: each file
    must name one of them and each of them must have a file (UserError otherwise)."""
    by_name = {spec.name: spec for spec in specs}
    files = sorted(Path(folder).glob("*.json")) if Path(folder).is_dir() else []
    if not files:
        raise UserError(f"session folder {folder} holds no *.json path files", "record sessions in gigan-web")
    sessions: dict[str, list[PathFile]] = {name: [] for name in by_name}
    for file in files:
        doc = _load(file)
        scene = doc.get("scene") if isinstance(doc, dict) else None
        if not isinstance(scene, str) or scene not in by_name:
            raise UserError(
                f"path file {file} is for scene {scene!r:.60}, not one of {', '.join(by_name)}",
                "add its scene to --scenes or move the file out of the folder",
            )
        sessions[scene].append(path_document(doc, by_name[scene], str(file)))
    empty = [name for name, found in sessions.items() if not found]
    if empty:
        raise UserError(
            f"session folder {folder} has no session of {', '.join(empty)}", "record one, or drop the scene"
        )
    return sessions
