"""A ``cloudbaking-client`` run (docs/architecture.md, Client loop): what it learns from the server at start-up
(:func:`check_server`), its config (:class:`CloudClientConfig`), the path flown composing with the server's maps
(:func:`run_client`), its per-frame perceived latency and per-request rows, what a run's files give back
(:class:`RunMetrics`), and the fewest requests that could serve a path (:func:`request_floors`).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import httpx
import numpy as np

from baseline_cloudbaking.client import RECORD_COLUMNS, STAGES, RemoteConfig, RemoteSource
from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC
from baseline_cloudbaking.fetch import FetcherName
from baseline_cloudbaking.request_policy import HOLDS, PREFETCH, LightCell, RequestPolicy, covers, viewpoint_of
from baseline_cloudbaking.viewpoints import Tolerance, nearest
from gicore.camera import Camera
from gicore.frame_rows import read_csv_rows, scored_ssim
from gicore.gi_map import GIMap
from gicore.run_config import PathRunConfig

if TYPE_CHECKING:
    from baseline_cloudbaking.gl_warp import GLPixelWarp
    from baseline_cloudbaking.warp import PixelWarp
    from gicore.path_file import PathFile
    from gicore.paths import Light
    from gicore.render import Renderer
    from gicore.scene import SceneSpec

#: Columns of ``requests.csv``: a request's record, then what the frame that bound its map spent on it.
REQUEST_COLUMNS = (*RECORD_COLUMNS, "bound_frame", "di_ms", "bind_ms", "warp_ms", "blend_ms", "total_ms")
#: The stages of a shown map's interaction latency in the order it goes through them (``requests.csv``'s ``*_ms``
#: columns; ``warp``: the bind and the per-frame warp): :data:`TRANSMISSION_PARTS` are the parts of
#: ``transmission``, not added again.
REQUEST_STAGES = ("transmission", "request", "transfer", "lookup", "read", "render", "denoise", "encode",
                  "server_other", "decode", "di", "warp", "blend")  # fmt: skip
TRANSMISSION_PARTS = ("request", "transfer")


@dataclass(frozen=True)
class ServerInfo:
    """What the client learns from the server at start-up (``GET /v1/scenes``)."""

    #: Δp / Δθ of the server's GI tree: the client asks again once its view leaves them.
    tolerance_position: float
    tolerance_angle_deg: float
    #: Side of the scene's light cells in the tree's keys (None: its light is static, no light level).
    light_cell: float | None = None

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_position, self.tolerance_angle_deg)


def check_server(server: str, scene: str, resolution: int, codec: str, spp: int, timeout_s: float) -> ServerInfo:
    """Ask the server for its health and scenes; a :class:`~gicore.error_policy.UserError` naming the option at
    fault if it is unreachable, is not a cloud-baking server, or does not serve what the client needs."""
    from gicore.error_policy import UserError

    try:
        url = httpx.URL(server)
    except httpx.InvalidURL as exc:
        raise UserError(
            f"--server {server!r} is not a URL ({exc})", "give the server's base URL, e.g. http://127.0.0.1:8000"
        ) from None
    if url.scheme not in ("http", "https") or not url.host:
        raise UserError(
            f"--server {server!r} is not an http(s) URL", "give the server's base URL, e.g. http://127.0.0.1:8000"
        )
    try:
        with httpx.Client(base_url=url, timeout=timeout_s) as client:
            health = client.get("/v1/health")
            scenes = client.get("/v1/scenes") if health.status_code == 200 else health
    except httpx.TimeoutException:
        raise UserError(
            f"--server {server}: no answer to GET /v1/health within {timeout_s:g} s",
            "check the server and the network to it",
        ) from None
    except httpx.TransportError as exc:
        raise UserError(
            f"--server {server}: cannot connect ({exc})", "start cloudbaking-server there, or fix the URL"
        ) from None
    try:
        if health.status_code != 200 or health.json().get("status") != "ok" or scenes.status_code != 200:
            raise ValueError
        info = scenes.json()
        served = {s["name"]: s for s in info["scenes"]}
        resolutions, codecs, max_spp = info["resolutions"], info["codecs"], int(info["max_spp"])
        cell = served[scene].get("light_cell") if scene in served else None
        tolerance = ServerInfo(
            float(info["tolerance_position"]), float(info["tolerance_angle_deg"]), None if cell is None else float(cell)
        )
    except (ValueError, KeyError, TypeError):
        what = f"--server {server} does not answer like a cloudbaking-server (GET /v1/health: {health.status_code})"
        raise UserError(what, "check the URL") from None
    if scene not in served:
        todo = f"use one of {', '.join(sorted(served))}, or start the server with its spec in --scenes"
        raise UserError(f"--scene {scene!r} is not served by {server}", todo)
    if resolution not in resolutions:
        raise UserError(
            f"--resolution {resolution} is not served by {server}", f"use one of {', '.join(map(str, resolutions))}"
        )
    if codec not in codecs:
        raise UserError(f"--codec {codec!r} is not served by {server}", f"use one of {', '.join(codecs)}")
    if spp > max_spp:
        raise UserError(f"--spp {spp} exceeds the server's max_spp {max_spp}", f"use --spp {max_spp} or less")
    return tolerance


#: Field metadata of a client timeout, s.
TIMEOUT_S = {"min": 0.001, "max": 3600.0}


@dataclass(frozen=True)
class CloudClientConfig(PathRunConfig):
    """One ``cloudbaking-client`` run: the shared path run (the same path as ``gigan-client``'s; ``spp`` is
    also the server's; the server's maps are always denoised) plus the GI-map codec and the timeouts of its
    requests. The server knows the scene by its name (a spec file's stem). Its command line is derived from
    these fields and :class:`~gicore.run_config.PathRunConfig`'s."""

    #: GI-map codec.
    codec: Literal[CODEC_NAMES] = DEFAULT_CODEC  # type: ignore[valid-type]
    #: Seconds to wait for a TCP connection.
    connect_timeout: float = field(default=RemoteConfig.connect_timeout_s, metadata=TIMEOUT_S)
    #: Seconds of silence that fail a request (bounds the server's render time).
    read_timeout: float = field(default=RemoteConfig.read_timeout_s, metadata=TIMEOUT_S)
    #: Seconds after which a request fails however it is going.
    deadline: float = field(default=RemoteConfig.deadline_s, metadata=TIMEOUT_S)
    #: When to ask: tolerance (only when no map held or in flight is within the server's tolerance of the view, by
    #: the GI tree's rule; -k is not used) or none (periodic: every k frames, and when the bound map leaves
    #: the tolerance).
    hold: Literal[HOLDS] = "tolerance"  # type: ignore[valid-type]
    #: Prefetch: none, or extrapolate (ask for the view the camera's recent motion reaches one measured request
    #: latency ahead; needs --hold tolerance).
    prefetch: Literal[PREFETCH] = "none"  # type: ignore[valid-type]
    #: Requests in flight at most, each on its own connection (with prefetch: successive views ahead, one
    #: tolerance crossing apart).
    in_flight: int = field(default=1, metadata={"min": 1, "max": 16})

    #: Where the requests and their decode run: process (a worker process per request in flight, which the frame
    #: loop never holds up) or thread (a thread of the client's process, which waits for the frame loop at every
    #: step that needs the interpreter).
    fetch: FetcherName = "process"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.prefetch != "none" and self.hold != "tolerance":
            raise ValueError(f"--prefetch {self.prefetch} needs --hold tolerance (it asks only when no map serves)")

    @property
    def server_name(self) -> str:
        return Path(self.scene).stem

    def policy(self, server: ServerInfo) -> RequestPolicy:
        """When to send requests to ``server`` (its tolerance and the scene's light cell)."""
        if self.hold == "none":  # the cell still names each map's light cell (perceived latency)
            return RequestPolicy(light_cell=server.light_cell, in_flight=self.in_flight)
        return RequestPolicy(server.tolerance, server.light_cell, self.prefetch, in_flight=self.in_flight)

    def remote(self, server: str, light_moves: bool) -> RemoteConfig:
        """What to ask ``server`` for: this run's maps (its resolution, codec and spp, the DI where the
        composition needs it) within its timeouts; ``light_moves``: whether the scene's light moves."""
        return RemoteConfig(
            server, self.server_name, self.resolution, self.codec, self.spp, di=self.composition == "residual",
            light_moves=light_moves, connect_timeout_s=self.connect_timeout, read_timeout_s=self.read_timeout,
            deadline_s=self.deadline, fetch=self.fetch,
        )  # fmt: skip


def open_cloud_warp(
    spec: SceneSpec, raster: str, resolution: int, composition: str, renderer: Renderer | None,
    backend: str = "auto", warn: bool = False,
) -> tuple[Any, str, PixelWarp | GLPixelWarp]:  # fmt: skip
    """The cloud client's raster renderer (``--renderer raster``; ``renderer``, Mitsuba's, where GL does not open),
    the name of the one that opened, and its warp of the ``composition``'s layer on ``--warp-backend backend``
    (:func:`gicore.gl.frame.warp_backend`). The warp's ``takes_display`` says whether the client asks for 8-bit
    maps as display values (the GL warp decodes them on the GPU)."""
    from baseline_cloudbaking.gl_warp import GLPixelWarp
    from baseline_cloudbaking.warp import PixelWarp
    from gicore.gi_map import LAYERS
    from gicore.gl.frame import open_client_raster, warp_backend

    opened, used = open_client_raster(raster, spec, resolution, renderer)
    layer = LAYERS[composition]
    warp = GLPixelWarp(opened, layer) if warp_backend(backend, used, warn=warn) == "gl" else PixelWarp(layer)
    return opened, used, warp


def run_client(
    cfg: CloudClientConfig, server: str, tolerance: ServerInfo, flown: PathFile | None = None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], str]:
    """Fly the run's path (``flown``; default: :func:`gicore.path_file.flown_path` of ``cfg``) composing with
    ``server``'s maps; returns (per-frame rows, per-request rows,
    the renderer that ran the per-frame raster passes: ``"mitsuba"`` when ``gl`` was asked and no GL context
    opened, see :func:`gicore.gl.frame.open_client_raster`).

    The local DI and the warp's surface-mask pass use ``cfg.renderer``, the warp and the composition
    ``cfg.warp_backend`` (:func:`gicore.gl.frame.warp_backend`); the GT stays with Mitsuba. Composed
    frames of scored frames are kept and scored against the GT after the run, so the GT renders neither
    delay frames nor change when requests go out. With ``cfg.hold`` tolerance the loop asks every frame and the
    source decides (:class:`RequestPolicy`). Each row also has :data:`PERCEIVED_COLUMNS`
    (:func:`perceived_latency`).
    """
    from gicore.loop import ClientLoop, FrameResult, LoopConfig, run_frames
    from gicore.path_file import flown_path
    from gicore.render import Renderer
    from gicore.scene import load_scene

    spec = load_scene(cfg.scene)
    renderer = Renderer(spec, cfg.resolution)
    raster, used, warp = open_cloud_warp(spec, cfg.renderer, cfg.resolution, cfg.composition, renderer,
                                         cfg.warp_backend, warn=True)  # fmt: skip
    remote = replace(cfg.remote(server, spec.light.moves), display=warp.takes_display)
    policy = cfg.policy(tolerance)
    held = policy.tolerance is not None
    loop_cfg = LoopConfig(
        every=1 if held else cfg.every, gi_fov=cfg.gi_fov_of(spec),
        max_move=None if held else tolerance.tolerance_position or None,
        max_turn=None if held else tolerance.tolerance_angle_deg or None, composition=cfg.composition, tau=cfg.tau,
        seed=cfg.seed, first_map_timeout_s=remote.connect_timeout_s + remote.deadline_s,
    )  # fmt: skip
    views = (flown or flown_path(spec, cfg, cfg.seed, cfg.local_fov_of(spec))).views(cfg.resolution)
    kept: dict[int, np.ndarray] = {}
    shown: list[tuple[float, float, GIMap | None, LightCell]] = []  # (start s, shown s, bound map, its cell)

    if cfg.fetch == "process":
        # the thread that takes a map over from its worker needs the interpreter for a moment; the frame loop
        # holds it, and gives it up only every switch interval (5 ms by default): ask for 0.5 ms
        sys.setswitchinterval(min(sys.getswitchinterval(), 0.0005))
    with RemoteSource(remote, policy) as source:
        loop = ClientLoop(loop_cfg, raster, source, warp)

        def keep(frame: int, result: FrameResult) -> None:
            end = time.perf_counter()
            gi = loop.bound
            cell = None if gi is None else source.cell_of(gi)
            shown.append((result.started - source.started_at, end - source.started_at, gi, cell))
            if cfg.gt_every and frame % cfg.gt_every == 0:
                kept[frame] = result.image

        rows = run_frames(loop, views, None, keep, cfg.frame_rate)
    gi_views = [(loop.gi_camera(camera), policy.cell(light)) for camera, light in views]
    perceived = perceived_latency(gi_views, shown, tolerance.tolerance)
    for row, extra in zip(rows, perceived, strict=True):
        row |= extra
    if kept:
        ground_truth = cfg.ground_truth(renderer, spec)
        for frame, image in kept.items():
            rows[frame] |= ground_truth.score(frame, *views[frame], image)
    return rows, join_requests(source.records, rows, tuple(s for s in warp.stages if s != "bind")), used


#: Per-frame columns of how long the frame's view waited for a map that serves it (:func:`perceived_latency`).
PERCEIVED_COLUMNS = ("start_s", "shown_s", "in_tolerance", "perceived_ms", "perceived_map")


def perceived_latency(
    views: list[tuple[Camera, LightCell]],
    shown: list[tuple[float, float, GIMap | None, LightCell]],
    tol: Tolerance,
) -> list[dict[str, Any]]:
    """The perceived latency, the time from a camera move to a frame with a map within tolerance, per
    frame (every frame of a path moves its camera): :data:`PERCEIVED_COLUMNS`, i.e.

    - ``start_s`` / ``shown_s``: when the frame started (its camera moved) and when it was composed;
    - ``in_tolerance``: 1 when the map the frame shows serves its own view (the GI tree's rule, :func:`covers`);
    - ``perceived_ms``: from the frame's start to the composition of the first frame, it or a later one, showing a
      map that serves this frame's view (``""`` when no frame of the run does: censored);
    - ``perceived_map``: the frame that requested that map (its ``frame`` in ``requests.csv``).

    ``views``: per frame, the GI camera and light cell; ``shown``: per frame, its start and composition (s), the
    map it showed (None: none yet) and that map's light cell.
    """
    segments: list[tuple[int, GIMap, LightCell]] = []  # (first frame, map, cell): runs of one shown map
    at: list[int] = []  # per frame: its first segment that may serve it (the one it shows, or the next)
    for frame, (_, _, gi, cell) in enumerate(shown):
        if gi is not None and (not segments or segments[-1][1] is not gi):
            segments.append((frame, gi, cell))
        at.append(len(segments) - 1 if gi is not None else len(segments))
    held = [viewpoint_of(gi.camera) for _, gi, _ in segments]
    eyes = np.array([v.eye for v in held]).reshape(-1, 3)
    dirs = np.array([v.direction for v in held]).reshape(-1, 3)
    cells = [cell for _, _, cell in segments]
    out = []
    for frame, ((camera, cell), (start, end, _, _)) in enumerate(zip(views, shown, strict=True)):
        row: dict[str, Any] = {
            "start_s": start,
            "shown_s": end,
            "in_tolerance": 0,
            "perceived_ms": "",
            "perceived_map": "",
        }
        later = [k for k in range(at[frame], len(segments)) if cells[k] == cell]
        if later and nearest(eyes[later], dirs[later], viewpoint_of(camera), tol) is not None:  # some map serves it
            k = next(k for k in later if covers(segments[k][1].camera, cells[k], camera, cell, tol))
            first = max(segments[k][0], frame)
            row |= {"in_tolerance": int(first == frame), "perceived_ms": (shown[first][1] - start) * 1e3}
            row["perceived_map"] = segments[k][1].frame
        out.append(row)
    return out


def join_requests(
    records: list[dict[str, Any]], rows: list[dict[str, Any]], warp_stages: tuple[str, ...]
) -> list[dict[str, Any]]:
    """Per-request rows: each record with what the frame that bound its map spent on its local render, bind,
    warp and blend, and ``total_ms``: every stage from the request to that frame's composition, summed (the
    frame's DI included: the map is not seen before it; the wait for the next frame, ``pickup_ms``, is not a
    stage and is not in it)."""
    bound: dict[int, dict[str, Any]] = {}  # the first frame that bound each map (a held map may be bound again)
    for r in rows:
        if r["gi_new"]:
            bound.setdefault(int(r["frame"]) - int(r["gi_age_frames"]), r)
    out = []
    for record in records:
        row = dict.fromkeys(REQUEST_COLUMNS, "") | record
        frame = bound.get(record["frame"])
        if record["status"] == "ok" and frame is not None:
            warp_ms = sum(float(frame[f"{s}_ms"]) for s in warp_stages)
            stages = sum(float(record[f"{s}_ms"]) for s in STAGES if record[f"{s}_ms"] != "")
            row |= {
                "bound_frame": frame["frame"],
                "di_ms": frame["di_ms"],
                "bind_ms": frame["bind_ms"],
                "warp_ms": warp_ms,
                "blend_ms": frame["compose_ms"],
            }
            local = float(frame["di_ms"]) + float(frame["bind_ms"]) + warp_ms + float(frame["compose_ms"])
            row["total_ms"] = stages + local
        out.append(row)
    return out


def request_summary(requests: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts by status and cache state, and median latency and total of the served requests."""
    ok = [r for r in requests if r["status"] == "ok"]
    statuses = [r["status"] for r in requests]
    summary: dict[str, Any] = {
        "requests": len(requests),
        "status": {s: statuses.count(s) for s in dict.fromkeys(statuses)},
    }
    summary |= {"hits": sum(int(r["hit"]) for r in ok), "misses": sum(1 - int(r["hit"]) for r in ok)}
    for column in ("latency_ms", "transmission_ms", "total_ms"):
        values = [float(r[column]) for r in ok if r[column] != ""]
        summary[f"median_{column}"] = float(np.median(values)) if values else None
    return summary


def _cell(value: str | None) -> float | None:
    return float(value) if value not in ("", None) else None


def stage_samples(requests: list[dict[str, str]]) -> dict[str, dict[str, list[float]]]:
    """Per-request stage times (ms) of a run's ``requests.csv`` rows by cache state (``hit``/``miss``), for the
    requests whose map was shown (a ``total``): :data:`REQUEST_STAGES`, ``total``, ``pickup``, ``server``, and the
    request and response bytes."""
    out: dict[str, dict[str, list[float]]] = {}
    for row in requests:
        if row["status"] != "ok" or row["total_ms"] == "":
            continue
        samples = out.setdefault("hit" if row["hit"] == "1" else "miss", {})
        values = {s: _cell(row[f"{s}_ms"]) for s in REQUEST_STAGES if s != "warp"}
        values |= {
            "warp": float(row["bind_ms"]) + float(row["warp_ms"]),
            "total": float(row["total_ms"]),
            "pickup": _cell(row["pickup_ms"]),
        }
        values |= {
            "bytes_up": float(row["bytes_up"]),
            "bytes_down": float(row["bytes_down"]),
            "server": float(row["server_ms"]),
        }
        for name, value in values.items():
            if value is not None:
                samples.setdefault(name, []).append(value)
    return out


@dataclass(frozen=True)
class RunMetrics:
    """What one ``cloudbaking-client`` run measured, read back from its ``frames.csv`` and ``requests.csv``
    (:meth:`read`)."""

    #: Perceived latency (ms, :func:`perceived_latency`) per frame by the cache state of the request whose map
    #: ended the wait: ``all`` (frames no map served as endless), ``hit`` and ``miss``.
    perceived: dict[str, list[float]]
    #: Share of frames whose shown map serves their own view.
    in_tolerance: float
    #: SSIM of each scored frame, by frame.
    ssim: dict[int, float]
    #: Requests sent, and those that failed (neither ``ok`` nor ``abandoned``).
    requests: int
    failed_requests: int
    #: Bytes sent and received over all requests.
    bytes_up: int
    bytes_down: int
    #: Latency (ms) of each request answered ``ok``.
    request_latency: list[float]
    #: Stage samples of the shown requests by cache state (:func:`stage_samples`).
    stages: dict[str, dict[str, list[float]]]

    @classmethod
    def read(cls, folder: Path) -> RunMetrics:
        """The metrics of the run whose files are under ``folder``."""
        frames, requests = read_csv_rows(folder / "frames.csv"), read_csv_rows(folder / "requests.csv")
        ok = [r for r in requests if r["status"] == "ok"]
        hit_of = {int(r["frame"]): r["hit"] == "1" for r in ok}
        perceived: dict[str, list[float]] = {"all": [], "hit": [], "miss": []}
        for row in frames:
            if row["perceived_ms"] == "":  # never served: in "all" as an endless wait
                perceived["all"].append(math.inf)
                continue
            value = float(row["perceived_ms"])
            perceived["all"].append(value)
            perceived["hit" if hit_of[int(row["perceived_map"])] else "miss"].append(value)
        return cls(
            perceived=perceived,
            in_tolerance=float(np.mean([int(r["in_tolerance"]) for r in frames])),
            ssim=scored_ssim(frames),
            requests=len(requests),
            failed_requests=sum(r["status"] not in ("ok", "abandoned") for r in requests),
            bytes_up=sum(int(r["bytes_up"]) for r in requests if r["bytes_up"] != ""),
            bytes_down=sum(int(r["bytes_down"]) for r in requests if r["bytes_down"] != ""),
            request_latency=[float(r["latency_ms"]) for r in ok],
            stages=stage_samples(requests),
        )

    @property
    def censored(self) -> int:
        """Frames no map of the run served (endless in :attr:`perceived`'s ``all``)."""
        return sum(math.isinf(v) for v in self.perceived["all"])

    @property
    def mean_ssim(self) -> float | None:
        """Mean SSIM of the scored frames (None: none scored)."""
        return float(np.mean(list(self.ssim.values()))) if self.ssim else None

    def quantiles(self, cache: str = "all") -> dict[str, float]:
        """Median and p95 of ``cache``'s perceived latency: order statistics, not interpolated, as frames no map
        served are endless."""
        waits = self.perceived[cache]
        return {
            stat: float(np.percentile(waits, q, method="inverted_cdf")) for stat, q in (("median", 50), ("p95", 95))
        }


def request_floors(
    views: Iterable[tuple[Camera, Light]], gi_fov: float, store: Path, scene: str, server: ServerInfo
) -> dict[str, int]:
    """The fewest requests that can serve every GI view (``gi_fov``) of a path's ``views`` by ``server``'s rule
    (:func:`~baseline_cloudbaking.viewpoints.fewest_maps`), with perfect foresight: ``prebaked``, from the maps of
    ``scene`` in ``store`` (no request policy sends fewer against it); ``placed``, from maps centred on the views
    themselves (a client choosing where maps are baked, on a cold store: each request a bake)."""
    from baseline_cloudbaking.store import GITree
    from baseline_cloudbaking.viewpoints import Viewpoint, fewest_maps, light_cell

    eyes, cells = [], []
    for camera, light in views:
        gi = camera.with_fov(gi_fov)
        eyes.append(Viewpoint.look_at(gi.origin, gi.target))
        cells.append(light_cell(light, server.light_cell))
    with GITree(store) as tree:
        stored = [(e.view, e.key.light_cell) for e in tree.entries(scene)]
    tol, own = server.tolerance, list(zip(eyes, cells, strict=True))
    return {"prebaked": fewest_maps(eyes, cells, stored, tol), "placed": fewest_maps(eyes, cells, own, tol)}
