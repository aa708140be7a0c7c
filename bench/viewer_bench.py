"""`bench web`: the Web3D viewer people use, measured in headless Chromium (Playwright, Debian's Chromium).

One run starts what ``gigan-web`` starts (its own ``cloudbaking-server`` on a store, prebaked along the path or
cold, and a ``network-sim proxy`` per profile; or ``--server URL``), loads the page, and per profile replays
a path file (``--path FILE``, else the scene's scripted path of ``--frames`` frames) through ``viewer.replay``:
the camera API the page's controls drive, one path frame per drawn frame, while GIGAN's inference runs off the
frame loop and cloud maps arrive when they arrive (:mod:`web3d.headless`). Per system and profile it reports
frame times (with a map in flight and without), frames drawn while each map was made, the age of the map each
frame shows, perceived latency, and each map's stages (:mod:`web3d.replay_stats`); GIGAN's checks; then
``session.run`` timed in the browser and in Python on one tensor, the prediction's parity with Python and the
WebGL2 port's buffers against GLRenderer's (:mod:`web3d.parity`). Also written: ``web_screenshot.png``
(both panes and their HUDs as the last replay draws its last path frame), ``web_session.json`` (every frame
the page drew, its camera and light: a path file the clients and benches replay) and, per profile, the bytes its
proxy carried (its chunk log). docs/architecture.md, bench web.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Literal

import numpy as np

from baseline_cloudbaking.client import request_path_maps
from bench.processes import pinned_server, run_place
from bench.runner import Bench, Block, Section
from bench.viewer_present import PARTS, SCREENSHOT
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.options import FRAMES, THREADS
from gicore.results import Results
from network_sim.profiles import profiles_field
from web3d.children import bytes_down
from web3d.headless import WEBGL_FLAGS, Segment, missing, replay, served_page
from web3d.parity import Reference, canvas_stats, time_inference
from web3d.replay_stats import CLOUD, GIGAN, Replayed, SystemStats, records

#: The page's recording of the whole run, a path file.
SESSION = "web_session.json"
#: The check: GIGAN's frame-time p95 with a map in flight at most this times its p95 without.
IN_FLIGHT_BOUND = 2.0


@dataclass(frozen=True)
class WebBenchConfig:
    """What one browser run measures (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="the one both systems fly through")
    #: Frames of the scripted path replayed.
    frames: int = field(default=60, metadata=FRAMES)
    orbit_frames: int = option_groups.orbit_frames()
    path: Path | None = option_groups.path()
    every: int = option_groups.every(10, note="while the view moves, each system asks at most this often")
    profiles: tuple[str, ...] = profiles_field(
        ("lan", "wan"), note="the cloud pane's maps come through each, one replay of the path each"
    )
    #: URL of a cloud-baking server to use instead of starting one (profile 'direct'; prebaked: filled first).
    server: str | None = field(default=None, metadata={"conflicts": ("profiles",)})
    #: The cloud-baking store: prebaked (every path frame's map baked first: the page's requests hit) or cold.
    store: Literal["prebaked", "cold"] = "prebaked"
    #: GI-map codec the cloud side asks for.
    codec: Literal["jpeg", "webp", "png"] = "jpeg"
    spp: int = option_groups.spp(note="of the cloud maps")
    #: ONNX model run in the browser and in Python (gigan-export output); absent: the shipped fp16 model.
    model: Path | None = None
    #: onnxruntime threads, in the browser (wasm) and in Python.
    threads: int = field(default=2, metadata=THREADS)
    #: session.run repetitions timed in the browser and in Python on the same input.
    timing_runs: int = field(default=10, metadata={"min": 1, "max": 1000})
    #: WebGL in Chromium: swiftshader (software, on the CPU), swiftshader_webgpu (also a software WebGPU adapter)
    #: or gpu (ANGLE on Vulkan, WebGPU).
    webgl: Literal["swiftshader", "swiftshader_webgpu", "gpu"] = "swiftshader"
    #: Seconds the page may take for one step (loading, settling, one replay).
    timeout_s: float = field(default=900.0, metadata={"max": 86400.0})

    @classmethod
    def quick(cls) -> WebBenchConfig:
        return cls(frames=20, every=10, spp=16, timing_runs=5)

    def check(self) -> None:
        if self.server is not None and not self.server.startswith(("http://", "https://")):
            raise UserError(
                f"--server {self.server!r} is not an http(s) URL", "give e.g. --server http://127.0.0.1:8001"
            )
        if self.model is not None:
            from gigan_local.inference import check_model_option

            check_model_option(self.model)


@dataclass(frozen=True)
class Viewer:
    """An open page (a Playwright Page) and what was started for it: ``doc`` the path file replayed, ``profiles``
    the page's, ``scene`` what the statistics need of the scene, ``children`` one line per child started,
    ``logs`` the folder of the proxies' per-chunk logs (None: no proxy started), complete once they stopped."""

    url: str
    page: Any
    doc: dict[str, Any]
    profiles: tuple[str, ...]
    scene: dict[str, Any]
    children: list[str]
    logs: Path | None


@contextmanager
def open_viewer(cfg: WebBenchConfig, results: Results) -> Iterator[Viewer]:
    """``gigan-web``'s site for ``cfg`` (its children started on a store prebaked first when asked) and the page
    open on it; work files in ``results.out / web_runs``."""
    from gicore.path_file import flown_path
    from gicore.paths import DEFAULT_LIGHT_CELL
    from web3d.cli import WebConfig, cloud_for, prepare

    spec, scenes_dir, work, plan, flown = run_place(cfg.scenes[0], results, "web_runs", False, cfg.path)
    doc = (flown if flown is not None else flown_path(spec, cfg, results.seed)).to_json()
    store = work / "store" if cfg.store == "prebaked" and cfg.server is None else None
    logs = None if cfg.server else work / "proxy_logs"
    for folder in (store, logs):
        if folder is not None:
            folder.mkdir()
    cloud_options = {"server": cfg.server} if cfg.server else {"profiles": cfg.profiles, "store": store}
    page_cfg = WebConfig(scene=cfg.scenes[0], listen="127.0.0.1:0", frames=len(doc["frames"]),
                         orbit_frames=cfg.orbit_frames, every=cfg.every, codec=cfg.codec, spp=cfg.spp,
                         threads=cfg.threads, seed=results.seed, assets=work / "assets", model=cfg.model,
                         **cloud_options)  # fmt: skip
    children: list[str] = []
    cloud = cloud_for(page_cfg, children.append, logs)
    site = prepare(page_cfg, cloud)
    n = int(site.config["resolution"])
    if cfg.store == "prebaked":  # every path frame's map baked before the page asks (a server of its own)
        run = SimpleNamespace(resolution=n, codec=cfg.codec, spp=cfg.spp, frames=cfg.frames, path=cfg.path,
                              orbit_frames=cfg.orbit_frames, read_timeout_s=cfg.timeout_s)  # fmt: skip
        if cfg.server:
            request_path_maps(cfg.server, cfg.scenes[0], run, results.seed)
        else:
            with pinned_server(plan, store, scenes_dir) as url:
                request_path_maps(url, cfg.scenes[0], run, results.seed)
    scene = {"name": spec.name, "gi_fov": spec.camera.gi_fov, "resolution": n,
             "light_cell": DEFAULT_LIGHT_CELL if spec.light.moves else None}  # fmt: skip
    with served_page(site, flags=WEBGL_FLAGS[cfg.webgl]) as (url, page):
        yield Viewer(url, page, doc, cloud.profiles, scene, children, logs)


def measure_viewer(viewer: Viewer, cfg: WebBenchConfig, results: Results) -> None:
    """The path replayed behind each profile (the screenshot as the last one drew its last path frame), then
    the session file, the inference timing and the parity checks, all into ``results``."""
    page = viewer.page
    last = viewer.profiles[-1]
    shot = {last: results.output(SCREENSHOT)}
    segments = [replay(page, viewer.doc, p, cfg.timeout_s, shot.get(p)) for p in viewer.profiles]
    data = records(page)
    results.output(SESSION).write_text(json.dumps(data["session"]))
    reference = Reference(cfg.threads, cfg.scenes[0], cfg.model)
    browser_ms, python_ms = time_inference(page, reference.check(data["parity"]), cfg.timing_runs)
    results.settings["browser"] = data["info"] | {"chromium": page.context.browser.version}
    common = settings(cfg, data["info"], len(viewer.doc["frames"]))
    record(results, viewer.scene, segments, data, common)
    for profile in viewer.profiles:  # over the whole run, as the proxies' logs count
        got = sum(m["bytes"] for m in data["maps"] if m.get("profile") == profile)
        results.add(system=CLOUD, scene=viewer.scene["name"], metric="map_bytes", value=got, unit="bytes", **common,
                    profile=profile)  # fmt: skip
    checks = {"diff": reference.diff, "port": reference.port, "browser_ms": browser_ms, "python_ms": python_ms}
    record_checks_and_timing(results, viewer.scene["name"], data["snapshot"], checks, common)


def settings(cfg: WebBenchConfig, info: dict[str, Any], frames: int) -> dict[str, Any]:
    """The run's settings every row carries."""
    return {
        "frames": frames,
        "every": cfg.every,
        "path": str(cfg.path) if cfg.path else "scripted",
        "store": cfg.store,
        "codec": cfg.codec,
        "spp": cfg.spp,
        "webgl": info.get("renderer", "?"),
        "backend": info.get("backend", "?"),
        "threads": info.get("wasm_threads", cfg.threads),
        "model": str(cfg.model) if cfg.model else "shipped (fp16)",
    }


def record(res: Results, scene: dict[str, Any], segments: list[Segment], data: dict, common: dict) -> None:
    """Per replay: both systems' rows, GIGAN's checks and the ratio of the median totals."""
    for segment in segments:
        run = Replayed.of(segment, data["frames"], data["maps"], data["session"]["frames"])
        stats = {system: record_system(res, run, system, scene, common) for system in (GIGAN, CLOUD)}
        totals = {s: float(np.median(x.stages["total"])) if x.frames else math.nan for s, x in stats.items()}
        record_checks(res, stats[GIGAN], scene["name"], common | {"profile": run.profile})
        ratio = totals[CLOUD] / totals[GIGAN]
        res.add(system="both", scene=scene["name"], metric="total_ratio", value=ratio, unit="x", **common,
                profile=run.profile)  # fmt: skip


def _ms_as_s(values: list[float]) -> list[float]:
    return [v / 1e3 for v in values]


def _summary(res: Results, metric: str, values: list[float], unit: str, **where: Any) -> None:
    for stat, value in (("median", np.median(values)), ("p95", np.percentile(values, 95))):
        res.add(metric=metric, value=float(value), unit=unit, stat=stat, **where)


def record_system(res: Results, run: Replayed, system: str, scene: dict, common: dict) -> SystemStats:
    """The rows of ``system``'s measures in one replay (:class:`web3d.replay_stats.SystemStats`): per map
    (``stat = map``) and summarised; ``scene``: name, gi_fov, resolution, light cell. Returns the measures."""
    stats = SystemStats.of(run, system, scene["gi_fov"], scene["resolution"], scene["light_cell"])
    where = {"system": system, "scene": scene["name"]} | common | {"profile": run.profile}
    for stage, values in stats.stages.items():
        if values:
            res.add_timing(metric=stage, samples_s=_ms_as_s(values), **where)
        for frame, v in zip(stats.frames, values):
            res.add(metric=stage, value=v, unit="ms", stat="map", **where, frame=frame)
    for phase, values in stats.phases.items():
        if values:
            res.add_timing(metric="frame_ms", samples_s=_ms_as_s(values), **where, phase=phase)
    during = stats.during
    for frame, count in during.items():
        res.add(metric="frames_during_map", value=count, unit="frames", stat="map", **where, frame=frame)
    if during:
        for stat, value in (("min", min(during.values())), ("median", float(np.median(list(during.values()))))):
            res.add(metric="frames_during_map", value=value, unit="frames", stat=stat, **where)
    if stats.age_ms:
        res.add_timing(metric="map_age_ms", samples_s=_ms_as_s(stats.age_ms), **where)
        _summary(res, "map_age_frames", stats.age_frames, "frames", **where)
    if stats.served:
        res.add_timing(metric="perceived_ms", samples_s=_ms_as_s(stats.served), **where)
    res.add(metric="censored", value=len(stats.perceived) - len(stats.served), unit="frames", **where)
    if stats.perceived:
        share = float(np.mean([r["in_tolerance"] for r in stats.perceived]))
        res.add(metric="in_tolerance", value=share, unit="fraction", **where)
    if stats.hit_rate is not None:
        res.add(metric="hit_rate", value=stats.hit_rate, unit="fraction", **where)
    return stats


def record_checks(res: Results, gigan: SystemStats, scene: str, common: dict[str, Any]) -> None:
    """The two checks on GIGAN's pane in one replay, as ``target_met`` rows (NaN: not measured in this replay)."""
    where = {"system": GIGAN, "scene": scene} | common
    flight, idle = gigan.phases["in_flight"], gigan.phases["idle"]
    measured = float(np.percentile(flight, 95)) if flight else math.nan
    baseline = float(np.percentile(idle, 95)) if idle else math.nan
    ratio = measured / baseline if baseline > 0 else math.nan
    met = math.nan if math.isnan(ratio) else float(ratio <= IN_FLIGHT_BOUND)
    res.add(metric="frame_ms", value=met, unit="bool", stat="target_met", **where, ratio=ratio, measured=measured,
            bound=IN_FLIGHT_BOUND * baseline, target=f"frame-time p95 with a map in flight <= {IN_FLIGHT_BOUND:g} x "
            "its p95 with none (ms)")  # fmt: skip
    during = gigan.during
    fewest = min(during.values()) if during else math.nan
    met = math.nan if not during else float(fewest >= 1)
    res.add(metric="frames_during_map", value=met, unit="bool", stat="target_met", **where, measured=fewest,
            bound=1, target="frames drawn while each map was made: fewest >= 1")  # fmt: skip


def record_checks_and_timing(res: Results, scene: str, snapshot: dict, checks: dict, common: dict) -> None:
    """``session.run`` in both runtimes, the parity and port checks, and what the last frames' canvases show."""
    for runtime, values in (("onnxruntime-web", checks["browser_ms"]), ("onnxruntime-python", checks["python_ms"])):
        res.add_timing(system=GIGAN, scene=scene, metric="inference_run", samples_s=_ms_as_s(values),
                       **common, runtime=runtime)  # fmt: skip
    ratio = float(np.median(checks["browser_ms"]) / np.median(checks["python_ms"]))
    res.add(system=GIGAN, scene=scene, metric="inference_ratio", value=ratio, unit="x", **common)
    for page_system, stats in canvas_stats(snapshot).items():
        system = GIGAN if page_system == "gigan" else CLOUD
        res.add(system=system, scene=scene, metric="canvas_lit", value=stats["lit"], unit="fraction", **common)
        res.add(system=system, scene=scene, metric="canvas_vs_di", value=stats["vs_di"], unit="tonemapped", **common)
    for name, value in checks["port"].items():  # the WebGL2 port against GLRenderer (gicore.gl)
        res.add(system=GIGAN, scene=scene, metric=f"port_{name}", value=value, unit="fraction", **common)
    for stat in ("max", "mean"):
        value = checks["diff"][stat]
        res.add(system=GIGAN, scene=scene, metric=f"parity_{stat}_abs_diff", value=value, unit="tonemapped", **common)


def record_links(res: Results, viewer: Viewer) -> None:
    """Per profile, the bytes its proxy carried down to the page over the run (its chunk log, complete once the
    proxy stopped): beside ``map_bytes``, the maps the page got through that profile."""
    if viewer.logs is None:
        return
    for profile in viewer.profiles:
        res.add(system=CLOUD, scene=viewer.scene["name"], metric="link_bytes_down",
                value=bytes_down(viewer.logs, profile), unit="bytes", profile=profile)  # fmt: skip


def measure(cfg: WebBenchConfig, results: Results) -> None:
    why = missing()
    if why:
        raise UserError(f"bench web cannot run: {why}", "install what is missing, then run it again")
    shutil.rmtree(results.out / "web_runs", ignore_errors=True)
    with open_viewer(cfg, results) as viewer:
        measure_viewer(viewer, cfg, results)
    record_links(results, viewer)
    shutil.rmtree(results.out / "web_runs", ignore_errors=True)
    shot = (results.out / SCREENSHOT).resolve()
    results.add(system="both", scene=viewer.scene["name"], metric="screenshot", value=shot.stat().st_size,
                unit="bytes", file=str(shot))  # fmt: skip


BENCH = Bench(
    "web",
    WebBenchConfig,
    measure,
    help="The Web3D viewer in headless Chromium: a path replayed through its camera controls, both systems side by "
    "side per network profile (frame times, map age, perceived latency, stages)",
    dashboard=Section("web", "Web3D viewer: the client people use", 15),
    readme=Block("Web3D viewer", 15),
    parts=PARTS,
    needs=("frame_ms", "total_ratio", "parity_max_abs_diff"),
)
