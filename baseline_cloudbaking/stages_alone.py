"""The cloud-baking client's stages alone (docs/architecture.md, Each stage alone): the same work as a client run,
on the same inputs and cameras, with nothing else running in the process, so that a stage's cost in the loop can
be set beside its cost alone (their ratio, the inflation, is what the client's plumbing adds):

- :func:`requests_alone`: each map of a path asked for one at a time (``request``, ``transfer``, the server's
  stages, ``decode``);
- :func:`local_alone`: the maps received composed along the path by the client's own loop, fed by a source that
  hands them over at once (``di``, ``warp``, ``blend``);
- :func:`decode_floor`: the libraries' floor of a decode, Pillow's decode of the map section plus zstandard's of
  the depth section, beside the client's own decodes of the same bytes (to linear radiance, and to display
  values for a GL warp).

``bench latency`` runs them, pinned to the clients' cores, beside GIGAN's loop.
"""

from __future__ import annotations

import io
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from baseline_cloudbaking.client import PathRequests, RemoteConfig, RemoteSource
from baseline_cloudbaking.client_run import REQUEST_STAGES
from gicore.gi_map import GIMap
from gicore.loop import SynchronousSource, Warp

if TYPE_CHECKING:
    from gicore.camera import Camera
    from gicore.paths import Light
    from gicore.scene import SceneSpec

Samples = dict[str, list[float]]


class AloneRuns(PathRequests, Protocol):
    """What the stages alone read of their caller's config (``bench latency``'s): the path's requests, every
    ``every`` frames, composed by ``composition``, at the loop's pace (``frame_rate`` frames/s; 0: unpaced). The
    pace is a condition of the run, not the client's plumbing: a request after a frame's idle wait wakes sleeping
    threads in the client, proxy and server, which back-to-back requests never do."""

    every: int
    composition: str
    frame_rate: float


#: The cloud stages a served request reports (``warp`` is the bind plus the warp's per-frame stages).
CLOUD_ALONE = tuple(s for s in REQUEST_STAGES if s not in ("render", "denoise", "encode"))


class ReplaySource(SynchronousSource):
    """Hands over the given maps one per request, in order and at once (the network and the decode left out)."""

    name = "replay"

    def __init__(self, maps: list[GIMap]):
        super().__init__()
        self._maps = [replace(gi, stages={}) for gi in maps]
        self._next = 0

    def produce(self, camera: Camera, light: Light, frame: int) -> GIMap:
        if frame < 0:  # the warm-up: any map
            return self._maps[0]
        gi = self._maps[self._next % len(self._maps)]
        self._next += 1
        return gi


def requests_alone(
    url: str, scene: str, spec: SceneSpec, cfg: AloneRuns, views: list[tuple[Camera, Light]], display: bool = False
) -> tuple[Samples, list[GIMap]]:
    """Ask ``url`` for the GI view of every k-th frame, one request at a time in a thread of this process (nothing
    else runs), each when the loop's frame would ask it: the stage samples of the served requests
    (:data:`CLOUD_ALONE`'s network and server stages, ``transmission``, and the request's latency as
    ``round_trip``) and the maps received; ``display``: 8-bit maps kept as display values, as a client whose warp
    decodes them (:attr:`RemoteConfig.display`)."""
    remote = RemoteConfig(url, Path(scene).stem, cfg.resolution, cfg.codec, cfg.spp, cfg.composition == "residual",
                          spec.light.moves, read_timeout_s=cfg.read_timeout_s, deadline_s=2 * cfg.read_timeout_s,
                          retry_after_s=0.0, fetch="thread", display=display)  # fmt: skip
    maps: list[GIMap] = []
    with RemoteSource(remote) as source:
        source.warm_up(*views[0])
        start = time.perf_counter()
        for frame in range(0, len(views), cfg.every):
            camera, light = views[frame]
            if cfg.frame_rate:  # asked when the loop's frame would ask: frame / frame_rate after the first
                time.sleep(max(0.0, start + frame / cfg.frame_rate - time.perf_counter()))
            source.request(camera.with_fov(spec.camera.gi_fov), light, frame)
            source.wait(2 * cfg.read_timeout_s + 10)
            gi = source.latest()
            if gi is not None and gi.frame == frame:
                maps.append(gi)
    samples: Samples = {}
    columns = {stage: f"{stage}_ms" for stage in CLOUD_ALONE} | {"round_trip": "latency_ms", "server": "server_ms"}
    for record in (r for r in source.records if r["status"] == "ok"):
        for stage, column in columns.items():
            if record.get(column, "") != "":
                samples.setdefault(stage, []).append(float(record[column]))
    if not maps:
        raise RuntimeError(f"no map came back from {url} while measuring the requests alone")
    return samples, maps


def local_alone(
    spec: SceneSpec, cfg: AloneRuns, views: list[tuple[Camera, Light]], maps: list[GIMap], raster: Any, warp: Warp
) -> Samples:
    """The cloud client's loop along the path on ``raster`` with ``warp`` (those of
    :func:`baseline_cloudbaking.client_run.open_cloud_warp`) and ``maps`` handed over every k frames: per bound
    map, ``di``, ``warp`` (bind + the warp's stages) and ``blend`` (the composition); frames at the loop's pace."""
    from gicore.loop import ClientLoop, LoopConfig, run_frames

    loop_cfg = LoopConfig(every=cfg.every, gi_fov=spec.camera.gi_fov, composition=cfg.composition, seed=0)
    loop = ClientLoop(loop_cfg, raster, ReplaySource(maps), warp)
    rows = run_frames(loop, views, frame_rate=cfg.frame_rate or None)
    warp_stages = [s for s in warp.stages if s != "bind"]
    samples: Samples = {"di": [], "warp": [], "blend": []}
    for row in (r for r in rows if r["gi_new"]):
        samples["di"].append(float(row["di_ms"]))
        samples["warp"].append(float(row["bind_ms"]) + sum(float(row[f"{s}_ms"]) for s in warp_stages))
        samples["blend"].append(float(row["compose_ms"]))
    return samples


def decode_floor(payloads: list[bytes], repeats: int = 3) -> dict[str, list[float]]:
    """Per stored payload (ms, the median of ``repeats``): ``decode`` (the client's :func:`decode_payload` to linear
    radiance, for a warp on the host), ``display`` (to an 8-bit codec's display values, for a warp that decodes
    them on the GPU) and ``library`` (Pillow's decode of the map section to RGB bytes plus zstandard's of the depth
    section: what no decode of these bytes can skip)."""
    import zstandard
    from PIL import Image

    from baseline_cloudbaking.codecs import ARRAY_HEADER_BYTES
    from baseline_cloudbaking.protocol import decode_payload, unpack

    def timed(work) -> float:
        times = []
        for _ in range(repeats + 1):  # the first is a warm-up
            t0 = time.perf_counter()
            work()
            times.append((time.perf_counter() - t0) * 1e3)
        return float(np.median(times[1:]))

    def library(data: bytes) -> None:
        _, sections = unpack(data)
        with Image.open(io.BytesIO(sections["gi"])) as im:
            np.asarray(im.convert("RGB"))
        zstandard.ZstdDecompressor().decompress(sections["depth"][ARRAY_HEADER_BYTES:])

    out: dict[str, list[float]] = {"decode": [], "display": [], "library": []}
    for data in payloads:
        out["decode"].append(timed(lambda: decode_payload(data)))
        out["display"].append(timed(lambda: decode_payload(data, display=True)))
        out["library"].append(timed(lambda: library(data)))
    return out


def stored_payloads(store: Path, scene: str, limit: int = 40) -> list[bytes]:
    """Up to ``limit`` payloads of ``scene`` in the GI tree at ``store`` (what its hits serve)."""
    from baseline_cloudbaking.store import GITree

    with GITree(store) as tree:
        return [tree.payload_path(e.sha).read_bytes() for e in tree.entries(scene)[:limit]]
