"""How the GI tree grows under user sessions: the frames of seeded or recorded sessions as the tree sees them,
the tree filled along them by the store's own lookup rule (:func:`baseline_cloudbaking.viewpoints.simulate_fill`),
what it holds once the whole navigable space has been visited, when it saturates or passes a size, and the bytes
an entry takes (measured on maps baked at entries spread over the tree)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from baseline_cloudbaking.bake import BakedMap, bake_map, gi_camera, map_header
from baseline_cloudbaking.codecs import DEPTH_CODEC, get_codec
from baseline_cloudbaking.protocol import pack
from baseline_cloudbaking.viewpoints import Tolerance, Viewpoint, light_cell, simulate_fill
from gicore.camera import Camera
from gicore.path_file import PathFile
from gicore.paths import Light, frame_seed, light_position
from gicore.render_cache import RenderCache
from gicore.scene import SceneSpec
from gicore.sessions import Session, navigable_views, session_views
from gicore.tonemap import tonemap

if TYPE_CHECKING:
    from gicore.render import Renderer

#: Frames of the light's schedule scanned for the light cells it reaches (the paper scenes' repeats every 2640).
LIGHT_SCAN_FRAMES = 20_000


def entry_frames(served: list[int]) -> list[int]:
    """The frame that created each entry (entries are numbered in insertion order)."""
    first: dict[int, int] = {}
    for frame, entry in enumerate(served):
        first.setdefault(entry, frame)
    return [first[e] for e in range(len(first))]


@dataclass(frozen=True)
class SessionFrames:
    """Every frame of a run of sessions as the GI tree sees it: GI camera and light, viewpoint, light cell
    (None for a static light), and the frame count after each session."""

    frames: list[tuple[Camera, Light]]
    views: list[Viewpoint]
    cells: list[tuple[int, int, int] | None]
    ends: np.ndarray


@dataclass(frozen=True)
class SessionFill:
    """The GI tree filled by the lookup rule along sessions: entries after each session, and the frame (GI
    camera, light) that created each entry, in insertion order."""

    entries: np.ndarray
    creators: list[tuple[Camera, Light]]


def session_frames(
    spec: SceneSpec, sessions: Sequence[Session | PathFile], light_cell_size: float, fov: float
) -> SessionFrames:
    """The frames of ``sessions`` in turn at GI FOV ``fov``: seeded ones (:func:`gicore.sessions.session_views`)
    or recorded ones (path files)."""
    size = light_cell_size if spec.light.moves else None
    frames: list[tuple[Camera, Light]] = []
    views: list[Viewpoint] = []
    ends = []
    for session in sessions:
        seen: dict[int, Viewpoint] = {}  # a session's laps repeat their cameras: one viewpoint per camera
        if isinstance(session, PathFile):
            flown = session.views(spec.resolution, fov)
        else:
            flown = session_views(spec, session, fov, spec.resolution)
        for cam, light in flown:
            if id(cam) not in seen:
                seen[id(cam)] = Viewpoint.look_at(cam.origin, cam.target)
            views.append(seen[id(cam)])
            frames.append((cam, light))
        ends.append(len(views))
    cells = [light_cell(light, size) for _, light in frames]
    return SessionFrames(frames, views, cells, np.asarray(ends))


def fill_sessions(run: SessionFrames, tol: Tolerance) -> SessionFill:
    """Walk the sessions' frames through one empty tree with the store's own rule
    (:func:`baseline_cloudbaking.viewpoints.simulate_fill`: nearest stored viewpoint within ``tol`` in the same
    light cell, else a new entry)."""
    served = simulate_fill(run.views, run.cells, tol)
    running = np.maximum.accumulate(served) + 1
    return SessionFill(running[run.ends - 1], [run.frames[f] for f in entry_frames(served)])


def capacity(spec: SceneSpec, tol: Tolerance, light_cell_size: float, samples: int, seed: int) -> dict[str, float]:
    """What the tree holds once every configuration has been visited, estimated: the lookup rule over
    ``samples`` viewpoints drawn uniformly from the navigable space (:func:`gicore.sessions.navigable_views`)
    fills one light cell; times the light cells the light's schedule reaches. A lower estimate while the
    last tenth of the samples still adds entries (``last_tenth_miss_rate``)."""
    views = [Viewpoint.look_at(eye, target) for eye, target in navigable_views(spec, samples, seed)]
    served = np.asarray(simulate_fill(views, [None] * samples, tol))
    per_cell = int(served.max()) + 1
    tail = served[int(0.9 * samples) :]
    before = int(served[: int(0.9 * samples)].max()) + 1 if samples >= 10 else 0
    size = light_cell_size if spec.light.moves else None
    cells = len({light_cell(light_position(spec, f), size) for f in range(LIGHT_SCAN_FRAMES)})
    return {
        "entries": per_cell * cells,
        "per_cell": per_cell,
        "light_cells": cells,
        "last_tenth_miss_rate": (per_cell - before) / max(len(tail), 1),
    }


def saturation_session(entries: np.ndarray, frames: int | np.ndarray, rate: float) -> int | None:
    """The session count after which no later session adds more than ``rate`` × ``frames`` entries (``frames``:
    one count for all, or each session's), with at
    least max(2, n // 10) sessions seen after it (else None: not saturated within the sessions run)."""
    added = np.diff(np.concatenate([[0], entries]))
    over = np.flatnonzero(added > rate * frames)
    k = int(over[-1]) + 1 if len(over) else 0  # sessions up to k still grew the tree by more
    return max(k, 1) if len(entries) - k >= max(2, len(entries) // 10) else None


def first_session_over(entries: np.ndarray, bytes_per_entry: float, limit: float) -> int | None:
    """The first session count whose tree (entries × bytes per entry) exceeds ``limit`` bytes, or None."""
    over = np.flatnonzero(entries * bytes_per_entry > limit)
    return int(over[0]) + 1 if len(over) else None


def spread_picks(n: int, want: int) -> list[int]:
    """Up to ``want`` indices of ``range(n)`` spread evenly, the first and the last included."""
    return sorted({int(round(k)) for k in np.linspace(0, n - 1, min(want, n))})


def rgb8(gi: np.ndarray) -> np.ndarray:
    """A GI map as the paper stores it: tone-mapped, 8 bits per channel, uncompressed (HxWx3 uint8)."""
    return np.round(np.clip(tonemap(gi), 0.0, 1.0) * 255.0).astype(np.uint8)


def cached_bake(
    cache: Path, renderer: Renderer, spec: SceneSpec, camera: Camera, light: Light, spp: int, seed: int
) -> BakedMap:
    """A GI map (GI + texel depth, no DI) from the render cache in ``cache``, baked and stored there on a miss:
    the maps behind the bytes per entry are the same on every run, and baked once."""

    def bake() -> dict[str, np.ndarray]:
        baked = bake_map(renderer, camera, light, spp, seed, di=False)
        times = np.array([baked.render_ms, baked.denoise_ms])
        return {"gi": baked.gi, "depth": baked.depth, "times_ms": times}

    key = ("gi_map", camera, list(light), spp, seed, renderer.resolution)
    entry = RenderCache(cache, spec).fetch(key, bake)
    return BakedMap(camera, entry["gi"], None, entry["depth"], *map(float, entry["times_ms"]))


def entry_bytes(
    spec: SceneSpec,
    name: str,
    creators: list[tuple[Camera, Light]],
    resolutions: Sequence[int],
    codecs: Sequence[str],
    *,
    spp: int,
    samples: int,
    cache: Path,
    seed: int,
) -> dict[tuple[int, str | None], list[int]]:
    """Bytes per entry of scene ``name``'s tree, measured on ``samples`` maps baked (:func:`cached_bake`) at the
    entries its ``creators`` made, spread over them (insertion order: over the sessions), per (resolution,
    codec): the stored payload (GI + depth, as the blend composition stores it) per codec, and under codec
    None the GI map uncompressed (:func:`rgb8`, the paper's accounting)."""
    from gicore.render import Renderer

    picks = spread_picks(len(creators), samples)
    sizes: dict[tuple[int, str | None], list[int]] = defaultdict(list)
    for resolution in resolutions:
        renderer = Renderer(spec, resolution)
        for i in picks:
            cam, light = creators[i]
            camera = gi_camera(spec, cam.origin, cam.target, cam.up, cam.fov, resolution)
            baked = cached_bake(cache, renderer, spec, camera, light, spp, frame_seed(seed, f"growth/{name}", i))
            sizes[(resolution, None)].append(len(rgb8(baked.gi).tobytes()))
            depth = DEPTH_CODEC.encode(baked.depth)
            for codec_name in codecs:
                header = map_header(baked, name, codec_name, spp, light if spec.light.moves else None, 0.0)
                sizes[(resolution, codec_name)].append(
                    len(pack(header, {"gi": get_codec(codec_name).encode(baked.gi), "depth": depth}))
                )
    return sizes
