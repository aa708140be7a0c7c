"""The map the server bakes, and the scene catalog it bakes from (docs/architecture.md, Cloud-baking server).

A GI map is exactly what GIGAN predicts: the ``gt`` buffer of the GIGAN dataset, i.e. the path-traced
image (max depth :data:`gicore.render.GT_MAX_DEPTH`) at the GI camera, OIDN-denoised with albedo and
normal guides (``gicore-dataset``'s default ``--denoise``), clipped at 0. With it travel the linear view
depth at texel centres (what both warps unproject) and, when asked, the DI of the GI view at 1 spp
(what the client renders per frame, so ``gi - di`` is the indirect light the residual composition
warps). A map with DI costs one more encoded image: about twice the bytes of a GI-only map.

A scene's *configuration space* (:func:`configuration_space`) is every GI map a client of the scene can
need, up to the GI tree's tolerance: GI-camera eyes on a grid over the camera's navigable envelope (orbit
radius and height within ``1 ± wobble`` of the spec's, azimuth within its arc), looking at the orbit target,
dense enough that every eye of the envelope, looking at any target the fly-through's target wobble reaches,
is within Δp and Δθ of a grid view; times every light cell the moving light reaches (one state for a
static light).
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from baseline_cloudbaking.codecs import DEPTH_CODEC, get_codec
from baseline_cloudbaking.protocol import pack
from baseline_cloudbaking.viewpoints import Tolerance, Viewpoint, light_cell
from gicore.camera import Camera
from gicore.paths import camera_path, light_position, light_range
from gicore.scene import SceneSpec, builtin_scenes, load_scene

if TYPE_CHECKING:
    from gicore.render import Renderer

Vec3 = tuple[float, float, float]
#: Scene names: no path separators or dots, so a name can never reach outside the scenes folder.
SCENE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}$")
SPEC_SUFFIXES = (".toml", ".json")


@dataclass(frozen=True)
class BakedMap:
    """A rendered GI map at ``camera`` (linear HxWx3), its GI view's DI (or None), texel-centre view
    depth (HxW, 0 = background) and what it cost (ms: render = path tracing + DI + depth pass,
    denoise = G-buffer guide pass + OIDN)."""

    camera: Camera
    gi: np.ndarray
    di: np.ndarray | None
    depth: np.ndarray
    render_ms: float
    denoise_ms: float


def bake_map(renderer: Renderer, camera: Camera, light: Vec3, spp: int, seed: int, di: bool) -> BakedMap:
    """Render the map at ``camera`` with the light at ``light`` (see the module docstring)."""
    t0 = time.perf_counter()
    gt = renderer.render_gt(camera, light, spp=spp, seed=seed)
    t1 = time.perf_counter()
    gi = np.maximum(renderer.denoise(gt, renderer.render_gbuffers(camera, seed=seed)), 0.0)
    t2 = time.perf_counter()
    di_img = renderer.render_di(camera, light, spp=1, seed=seed) if di else None
    texels = renderer.render_uv(camera)
    depth = np.where(texels["mask"], camera.view_depth(texels["position"]), 0.0).astype(np.float32)
    t3 = time.perf_counter()
    return BakedMap(camera, gi, di_img, depth, ((t1 - t0) + (t3 - t2)) * 1e3, (t2 - t1) * 1e3)


def encode_map(baked: BakedMap, scene: str, codec_name: str, spp: int, light: Vec3 | None) -> bytes:
    """The stored payload of a baked map (:mod:`baseline_cloudbaking.protocol`); ``light`` None for a
    static light (the header then names none)."""
    codec = get_codec(codec_name)
    t0 = time.perf_counter()
    sections = {"gi": codec.encode(baked.gi), "depth": DEPTH_CODEC.encode(baked.depth)}
    if baked.di is not None:
        sections["di"] = codec.encode(baked.di)
    return pack(map_header(baked, scene, codec_name, spp, light, (time.perf_counter() - t0) * 1e3), sections)


def map_header(baked: BakedMap, scene: str, codec_name: str, spp: int, light: Vec3 | None, encode_ms: float) -> dict:
    """The payload header of a baked map (what :func:`encode_map` packs with the encoded sections)."""
    cam = baked.camera
    header = {
        "format": "gimap/1",
        "scene": scene,
        "codec": codec_name,
        "resolution": cam.width,
        "spp": spp,
        "camera": cam.to_dict(),
        "view": cam.view().tolist(),
        "proj": cam.proj().tolist(),
        "bake_ms": {"render": baked.render_ms, "denoise": baked.denoise_ms, "encode": encode_ms},
    }
    return header | ({"light": list(light)} if light is not None else {})


def gi_camera(spec: SceneSpec, eye: Vec3, target: Vec3, up: Vec3, fov: float, resolution: int) -> Camera:
    """The GI camera of a request: the scene's near/far clip, a square film (ValueError if degenerate)."""
    return Camera(
        eye, target, up, fov=fov, near=spec.camera.near, far=spec.camera.far, width=resolution, height=resolution
    )


@dataclass(frozen=True)
class PathFrame:
    """One frame of a fly-through as the GI tree sees it: the GI camera, the light, the light cell
    (None for a static light) and the viewpoint."""

    camera: Camera
    light: Vec3
    cell: tuple[int, int, int] | None
    view: Viewpoint


def fly_through(
    spec: SceneSpec, frames: int, resolution: int, light_cell_size: float, seed: int = 0, fov: float | None = None
) -> list[PathFrame]:
    """The scene's camera path (GI-camera FOV unless ``fov``) and light schedule, as ``gicore-dataset``
    plans its training frames; the light cell applies only when the scene's light moves."""
    size = light_cell_size if spec.light.moves else None
    out = []
    for i, cam in enumerate(camera_path(spec, frames, seed=seed, fov=fov, resolution=resolution)):
        light = light_position(spec, i)
        out.append(PathFrame(cam, light, light_cell(light, size), Viewpoint.look_at(cam.origin, cam.target)))
    return out


#: Most grid views of one light state a configuration space may hold: a tighter tolerance is not bakeable.
SPACE_VIEWS_MAX = 10_000_000
#: Safety factor on the grid's covering radius, so that float rounding never leaves a view just outside.
COVER_MARGIN = 1.0 - 1e-9


@dataclass(frozen=True)
class ConfigurationSpace:
    """A scene's configuration space (see the module docstring): ``eyes`` (n x 3) all looking at
    ``target``, and the light states as (light cell or None for a static light, light position baked)."""

    eyes: np.ndarray
    target: Vec3
    lights: list[tuple[tuple[int, int, int] | None, Vec3]]
    #: Largest distance from an envelope eye to its nearest grid eye (scene units).
    cover: float
    #: Grid cells along azimuth, radius and height.
    grid: tuple[int, int, int]

    @property
    def size(self) -> int:
        """Maps the space holds: views x light states."""
        return len(self.eyes) * len(self.lights)

    def views(self) -> list[Viewpoint]:
        return [Viewpoint.look_at(tuple(eye), self.target) for eye in self.eyes]


def _centres(lo: float, hi: float, n: int) -> np.ndarray:
    """Centres of ``n`` equal cells over [lo, hi]."""
    return lo + (np.arange(n) + 0.5) * (hi - lo) / n


def light_states(spec: SceneSpec, cell_size: float) -> list[tuple[tuple[int, int, int] | None, Vec3]]:
    """Every light cell the scene's light reaches (its box: rest position ± amplitude in x and y), each
    with the centre of the part of the box inside it; a static light: one state, no cell."""
    light = spec.light
    if not light.moves:
        return [(None, tuple(map(float, light.position)))]
    low, high = light_range(spec)
    z = low[2]
    spans = [(low[0], high[0]), (low[1], high[1])]
    axes = []
    for lo, hi in spans:
        cells = range(math.floor(lo / cell_size), math.floor(hi / cell_size) + 1)
        axes.append([(max(lo, i * cell_size) + min(hi, (i + 1) * cell_size)) / 2 for i in cells])
    states: dict = {}
    for px in axes[0]:
        for py in axes[1]:
            pos = (float(px), float(py), float(z))
            states.setdefault(light_cell(pos, cell_size), pos)
    return sorted(states.items())


def configuration_space(spec: SceneSpec, tolerance: Tolerance, light_cell_size: float) -> ConfigurationSpace:
    """The configuration space of ``spec`` at ``tolerance`` (see the module docstring). ValueError when no
    grid covers it: a zero Δp, a Δθ within the target wobble's angle, or more than :data:`SPACE_VIEWS_MAX`
    views per light state."""
    c = spec.camera
    r_lo, r_hi = c.radius * (1.0 - c.wobble), c.radius * (1.0 + c.wobble)
    h_lo, h_hi = sorted((c.height * (1.0 - c.wobble), c.height * (1.0 + c.wobble)))
    full = c.azimuth_range >= 360.0
    a_lo = 0.0 if full else math.radians(c.azimuth_center - c.azimuth_range / 2)
    arc = math.radians(360.0 if full else c.azimuth_range)
    # Nearest an eye comes to the target, and the angle the fly-through's target wobble (0.1 x wobble in
    # x and y) can turn a view by: the grid gets the rest of the angle tolerance.
    dy = 0.0 if h_lo <= c.target[1] <= h_hi else min(abs(h_lo - c.target[1]), abs(h_hi - c.target[1]))
    rho = math.hypot(r_lo, dy)
    wobble_deg = math.degrees(math.asin(min(1.0, 0.1 * c.wobble * math.sqrt(2.0) / rho)))
    spare_deg = min(90.0, tolerance.angle_deg - wobble_deg)
    if tolerance.position <= 0.0 or spare_deg <= 0.0:
        raise ValueError(
            f"tolerance {tolerance.position:g} / {tolerance.angle_deg:g}° cannot cover the envelope: Δp must be "
            f"> 0 and Δθ above the target wobble's {wobble_deg:.3g}°"
        )
    # Two views d apart, both at least rho from the target, differ by at most asin(d / rho) in angle.
    cover = min(tolerance.position, rho * math.sin(math.radians(spare_deg))) * COVER_MARGIN
    # A cell of side s holds no point farther than sqrt(3) s / 2 from its centre; the arc's chord at the
    # outer radius is the longest (4 r r' sin²(da/2) <= (r_hi da)²).
    side = 2.0 * cover / math.sqrt(3.0)
    grid = tuple(max(1, math.ceil(extent / side)) for extent in (r_hi * arc, r_hi - r_lo, h_hi - h_lo))
    if math.prod(grid) > SPACE_VIEWS_MAX:
        raise ValueError(
            f"tolerance {tolerance.position:g} / {tolerance.angle_deg:g}° needs {math.prod(grid):,} views per "
            f"light state, more than {SPACE_VIEWS_MAX:,}"
        )
    a, r, h = np.meshgrid(
        _centres(a_lo, a_lo + arc, grid[0]), _centres(r_lo, r_hi, grid[1]), _centres(h_lo, h_hi, grid[2]), indexing="ij"
    )
    t = c.target
    eyes = np.stack([t[0] + r * np.sin(a), h, t[2] + r * np.cos(a)], axis=-1).reshape(-1, 3)
    return ConfigurationSpace(eyes, tuple(map(float, t)), light_states(spec, light_cell_size), cover, grid)


def spec_sha(spec: SceneSpec) -> str:
    """SHA-256 of a spec's canonical JSON: a store refuses to mix maps of two versions of a scene."""
    return hashlib.sha256(json.dumps(spec.to_dict(), sort_keys=True).encode()).hexdigest()


class UnknownScene(KeyError):
    """A scene name that is malformed or names no scene of the catalog."""

    def __str__(self) -> str:
        return str(self.args[0])


class SceneCatalog:
    """The scenes a server or prebake can bake: the built-in ones and the ``.toml``/``.json`` specs in
    ``scenes_dir`` (by file stem; a file shadows a built-in of the same name). Specs load lazily."""

    def __init__(self, scenes_dir: Path | None = None):
        self._files: dict[str, Path | str] = {name: name for name in builtin_scenes()}
        if scenes_dir is not None:
            for path in sorted(Path(scenes_dir).iterdir()):
                if path.suffix in SPEC_SUFFIXES and SCENE_NAME.match(path.stem):
                    self._files[path.stem] = path
        self._specs: dict[str, SceneSpec] = {}
        self._lock = threading.Lock()

    def names(self) -> list[str]:
        return sorted(self._files)

    def get(self, name: str) -> SceneSpec:
        """The spec of scene ``name``; UnknownScene if malformed or unknown, SceneSpecError if invalid."""
        if not SCENE_NAME.match(name):
            raise UnknownScene(
                f"scene name {name!r} is malformed: a letter or '_', then letters, digits or '_', at most 64"
            )
        if name not in self._files:
            raise UnknownScene(f"unknown scene {name!r}; known scenes: {', '.join(self.names())}")
        with self._lock:
            if name not in self._specs:
                self._specs[name] = load_scene(self._files[name])
            return self._specs[name]
