"""`bench web`: the browser-side Table 1. Playwright drives the Web3D viewer (``gigan-web``) headless in
Debian's Chromium, both systems flying the scene's camera path in one page.

One run starts a ``cloudbaking-server`` (prebaked along the path, or cold), a ``network-sim proxy --profile P``
and the viewer's server (:mod:`web3d.serve`), loads the page and waits for ``frames`` frames. Rows: each
stage's median, p95 and n over the GI maps as the page's HUD measures them, ``total_ratio``; ``session.run``
timed alternately in the browser and in Python on the same tensor (``inference_ratio``); the browser's
prediction against :class:`gigan_local.inference.GIModel`'s (``parity_*``); the WebGL2 port's buffers against
:class:`gicore.gl.GLRenderer`'s (``port_*``). Also written: ``web_screenshot.png``; the provenance records the
browser, its WebGL renderer and the onnxruntime-web backend. docs/architecture.md, bench web.
"""

from __future__ import annotations

import base64
import math
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bench.present.declarations import Column, Image, Rows, Table, fill, matches
from bench.runner import Bench, Block, Section
from gicore.error_policy import UserError
from gicore.options import FRAMES, SPP, THREADS
from gicore.results import Results

GIGAN, CLOUD = "gigan", "cloud_baking"
GIGAN_STAGES = ("gi_render", "inference", "warp", "blend")
CLOUD_STAGES = ("transmission", "server", "decode", "warp", "blend")
CHROMIUM = Path("/usr/bin/chromium")
#: Chromium's software WebGL2 (SwiftShader through ANGLE), for a machine without a GPU; ``swiftshader_webgpu``
#: also gives the page SwiftShader's WebGPU adapter (so onnxruntime-web's WebGPU back end runs, in software:
#: a functional check of that path, ~20 s per inference); ``gpu`` asks for the GPU through ANGLE's Vulkan back
#: end, with WebGPU.
_SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
WEBGL_FLAGS = {
    "swiftshader": _SWIFTSHADER,
    "swiftshader_webgpu": [*_SWIFTSHADER, "--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"],
    "gpu": ["--use-angle=vulkan", "--enable-features=Vulkan", "--ignore-gpu-blocklist", "--enable-unsafe-webgpu"],
}
SCREENSHOT = "web_screenshot.png"
#: The page's buffers compared with GLRenderer's (:func:`port_check`).
PORT_BUFFERS = ("di", "albedo", "normal", "depth")


@dataclass(frozen=True)
class WebBenchConfig:
    """What one browser run measures (see the module docstring)."""

    #: The scene both systems fly through (name or spec file).
    scenes: tuple[str, ...] = field(default=("lung_plane",), metadata={"max_len": 1})
    #: Frames the page plays.
    frames: int = field(default=60, metadata=FRAMES)
    #: GI-map period k: both systems make or fetch a new map every k frames.
    every: int = field(default=10, metadata=FRAMES)
    #: Network profile of the proxy between the page and the cloud-baking server (network-sim profiles).
    profile: str = "lan"
    #: The cloud-baking store: prebaked (filled along the path first: the page's requests hit) or cold (they miss).
    store: Literal["prebaked", "cold"] = "prebaked"
    #: GI-map codec the cloud side asks for.
    codec: Literal["jpeg", "webp", "png"] = "jpeg"
    #: Path-tracing samples per pixel of the cloud maps.
    spp: int = field(default=64, metadata=SPP)
    #: ONNX model run in the browser and in Python (gigan-export output); absent: the shipped fp16 model.
    model: Path | None = None
    #: onnxruntime threads, in the browser (wasm) and in Python.
    threads: int = field(default=2, metadata=THREADS)
    #: session.run repetitions timed in the browser and in Python on the same input.
    timing_runs: int = field(default=10, metadata={"min": 1, "max": 1000})
    #: WebGL in Chromium: swiftshader (software, on the CPU), swiftshader_webgpu (also a software WebGPU adapter)
    #: or gpu (ANGLE on Vulkan, WebGPU).
    webgl: Literal["swiftshader", "swiftshader_webgpu", "gpu"] = "swiftshader"
    #: Seconds the page may take to play its frames.
    timeout_s: float = field(default=900.0, metadata={"max": 86400.0})

    @classmethod
    def quick(cls) -> WebBenchConfig:
        return cls(frames=20, every=10, spp=16, timing_runs=5)

    def check(self) -> None:
        from network_sim.profiles import profiles

        if self.profile not in profiles():
            raise UserError(f"--profile {self.profile} is not a profile", f"pick one of {sorted(profiles())}")
        if self.model is not None:
            from gigan_local.inference import check_model_option

            check_model_option(self.model)


def require_browser() -> str | None:
    """Why the viewer cannot run here (no Chromium, no Playwright, no npm modules), or None."""
    from web3d.serve import WEB_DIR

    if not CHROMIUM.is_file():
        return f"{CHROMIUM} is missing (apt-get install chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install -e '.[test]')"
    if not (WEB_DIR / "node_modules" / "onnxruntime-web" / "dist").is_dir():
        return f"{WEB_DIR}/node_modules is missing (make setup runs npm ci in web/)"
    return None


def run_page(
    url: str, cfg: WebBenchConfig, screenshot: Path, reference: Callable[[dict[str, Any]], Callable[[], float]]
) -> dict[str, Any]:
    """Load the viewer at ``url`` in headless Chromium, wait until it has played its frames, screenshot both
    canvases, and time ``session.run`` ``cfg.timing_runs`` times in the page and in Python, alternately (both
    under the same load): ``reference(viewer)`` gives the Python run (one call: one run, seconds). Returns what
    ``window.viewer`` holds, with Chromium's version and both runs' times (ms); a page error raises RuntimeError
    with the page's message."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=WEBGL_FLAGS[cfg.webgl])
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"{url}/")
            page.wait_for_function("window.viewer && window.viewer.done", timeout=cfg.timeout_s * 1e3)
            data = page.evaluate("window.viewer")
            if data.get("error") or errors:
                raise RuntimeError(f"the viewer failed: {data.get('error') or errors[0]}")
            page.locator("#viewer").screenshot(path=str(screenshot))
            python_run = reference(data)
            data["browser_runs_ms"], data["python_runs_ms"] = [], []
            for _ in range(cfg.timing_runs):
                data["browser_runs_ms"].append(page.evaluate("window.viewer.infer()"))
                data["python_runs_ms"].append(python_run() * 1e3)
            data["snapshot"] = page.evaluate("window.viewer.snapshot()")
            data["hud"] = {system: page.inner_text(f"#hud-{system}") for system in ("gigan", "cloud")}
            data["chromium"] = browser.version
            return data
        finally:
            browser.close()


def _floats(text: str, n: int, channels: int) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype=np.float32).reshape(n, n, channels)


def canvas_stats(snapshot: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Per canvas of the page's last frame: ``lit``, the fraction of pixels brighter than 8/255 in some channel,
    and ``vs_di``, the mean |canvas - tonemap(DI)| over the lit pixels (0: the canvas shows its DI alone)."""
    from gicore.tonemap import tonemap

    out = {}
    for system, snap in snapshot.items():
        if snap is None:
            continue
        n = int(snap["resolution"])
        canvas = np.frombuffer(base64.b64decode(snap["canvas"]), np.uint8).reshape(n, n, 4)[..., :3] / 255.0
        di = np.rint(tonemap(_floats(snap["di"], n, 4)[..., :3]) * 255.0) / 255.0
        lit = (canvas > 8 / 255).any(axis=-1)
        out[system] = {"lit": float(lit.mean()), "vs_di": float(np.abs(canvas - di)[lit].mean()) if lit.any() else 0.0}
    return out


def port_check(scene: str, parity: dict[str, Any], frame: dict[str, np.ndarray]) -> dict[str, float]:
    """The page's DI + G-buffers against GLRenderer's at the same GI camera and light: the fraction of pixels
    whose coverage differs, and per buffer the mean |difference| over pixels both cover relative to the mean
    magnitude; empty where no GL context opens."""
    from gicore.camera import Camera
    from gicore.gl import GLRenderer, RasterUnavailable
    from gicore.scene import load_scene

    n = int(parity["resolution"])
    c = parity["camera"]
    camera = Camera(c["eye"], c["target"], fov=c["fov"], near=c["near"], far=c["far"], width=n, height=n)
    try:
        renderer = GLRenderer(load_scene(scene), n, lod=0)  # full detail drawn, shadow casters at SHADOW_LOD
        ours = renderer.render_di_gbuffers(camera, tuple(parity["light"]))
    except RasterUnavailable:
        return {}
    page_mask, gl_mask = frame["depth"][..., 0] > 0, ours["depth"][..., 0] > 0
    both = page_mask & gl_mask
    out = {"coverage_mismatch": float((page_mask != gl_mask).mean())}
    for name in PORT_BUFFERS:
        reference = np.abs(ours[name][both]).mean()
        out[f"{name}_rel_diff"] = float(np.abs(frame[name] - ours[name])[both].mean() / max(reference, 1e-12))
    return out


class Reference:
    """Python's side of the page's first GI map: :meth:`check` compares the browser's tone-mapped prediction with
    ``tonemap(GIModel.predict(buffers))`` on the G-buffers the page rendered (rows flipped from GL's bottom-up),
    and those buffers with :class:`gicore.gl.GLRenderer`'s at the same GI camera and light (the WebGL2 port of its
    shaders against the original; :attr:`port`, empty where no GL context opens), and returns one timed
    ``session.run`` on the predicted input (the tensor predict encoded), for :func:`run_page`."""

    def __init__(self, threads: int, scene: str, model: Path | None = None) -> None:
        self.threads, self.scene, self.model = threads, scene, model  # None: the shipped model
        self.diff: dict[str, float] = {}
        self.port: dict[str, float] = {}

    def check(self, viewer: dict[str, Any]) -> Callable[[], float]:
        from gicore.tonemap import tonemap
        from gigan_local.inference import DEFAULT_MODEL, GIModel

        p = viewer["parity"]
        n = int(p["resolution"])
        buffers = {k: _floats(p[k], n, 4)[::-1] for k in ("di", "albedo", "normal", "depth")}
        frame = {k: buffers[k][..., :3] for k in ("di", "albedo", "normal")} | {"depth": buffers["depth"][..., :1]}
        model = GIModel(self.model or DEFAULT_MODEL, threads=self.threads)
        diff = np.abs(tonemap(model.predict(frame)) - _floats(p["display"], n, 3))
        self.diff = {"max": float(diff.max()), "mean": float(diff.mean())}
        self.port = port_check(self.scene, p, frame)

        def run() -> float:
            t0 = time.perf_counter()
            model.session.run(None, {model.input_name: model._input})  # the input predict encoded
            return time.perf_counter() - t0

        return run


def _prefill(server: str, spec: Any, assets: Path, cfg: WebBenchConfig) -> None:
    """Ask the server (directly, not through the proxy) for every map the page will ask for, so they hit."""
    import httpx

    from gicore.path_file import read_path_file

    path = read_path_file(assets / "path.json", spec).frames
    with httpx.Client(timeout=600.0) as client:
        for f in range(0, min(cfg.frames, len(path)), cfg.every):
            gi = path[f].camera  # the page's GI camera: the frame's view at the scene's GI FOV
            body: dict[str, Any] = {
                "scene": spec.name,
                "camera": {"eye": gi.origin, "target": gi.target, "up": gi.up, "fov": spec.camera.gi_fov},
                "resolution": spec_resolution(assets),
                "codec": cfg.codec,
                "spp": cfg.spp,
            }
            if spec.light.moves:
                body["light"] = path[f].light
            client.post(f"{server}/v1/gimap", json=body).raise_for_status()


def spec_resolution(assets: Path) -> int:
    import json

    return int(json.loads((assets / "scene.json").read_text())["resolution"])


@contextmanager
def viewer_site(cfg: WebBenchConfig, seed: int, work: Path) -> Iterator[str]:
    """A ``cloudbaking-server`` (store in ``work``; filled along the path first when ``cfg.store`` is prebaked), a
    ``network-sim proxy`` in front of it and the viewer's server forwarding to the proxy; yields the page's URL."""
    from gicore.scene import load_scene
    from network_sim.process import Running
    from web3d.cli import WebConfig, cloud_for, prepare
    from web3d.serve import WebServer

    spec = load_scene(cfg.scenes[0])
    bin_dir = Path(sys.executable).parent
    server_argv = [str(bin_dir / "cloudbaking-server"), "--port", "0", "--store", str(work / "store")]
    with Running(server_argv, 120.0) as server:
        host, port = server.addr
        server_url = f"{host}:{port}"  # the server prints a URL
        argv = [sys.executable, "-m", "network_sim", "proxy", "--upstream", server_url.removeprefix("http://")]
        with Running([*argv, "--profile", cfg.profile, "--seed", str(seed)], 60.0) as proxy:
            page_cfg = WebConfig(
                scene=cfg.scenes[0],
                server=f"http://{proxy.addr[0]}:{proxy.addr[1]}",
                listen="127.0.0.1:0",
                frames=cfg.frames,
                every=cfg.every,
                codec=cfg.codec,
                spp=cfg.spp,
                threads=cfg.threads,
                seed=seed,
                assets=work / "assets",
                model=cfg.model,
            )
            site = prepare(page_cfg, cloud_for(page_cfg))
            if cfg.store == "prebaked":
                _prefill(server_url, spec, site.assets, cfg)
            with WebServer(site) as web:
                yield web.url


def measure(cfg: WebBenchConfig, results: Results) -> None:
    why = require_browser()
    if why:
        raise UserError(f"bench web cannot run: {why}", "install what is missing, then run it again")
    from gicore.scene import load_scene

    scene = load_scene(cfg.scenes[0]).name
    work = results.out / "web_runs"
    shutil.rmtree(work, ignore_errors=True)
    reference = Reference(cfg.threads, cfg.scenes[0], cfg.model)
    with viewer_site(cfg, results.seed, work) as url:
        viewer = run_page(url, cfg, results.output(SCREENSHOT), reference.check)
    shutil.rmtree(work, ignore_errors=True)
    results.settings["browser"] = viewer["info"] | {"chromium": viewer["chromium"]}
    record(results, scene, cfg, viewer, reference.diff, reference.port)
    shot = (results.out / SCREENSHOT).resolve()
    size = shot.stat().st_size
    results.add(system="both", scene=scene, metric="screenshot", value=size, unit="bytes", file=str(shot))


def record(
    res: Results,
    scene: str,
    cfg: WebBenchConfig,
    viewer: dict[str, Any],
    check: dict[str, Any],
    port: dict[str, float],
) -> None:
    """The CSV rows of one page run (module docstring)."""
    info = viewer["info"]
    common = {
        "frames": cfg.frames,
        "every": cfg.every,
        "profile": cfg.profile,
        "store": cfg.store,
        "codec": cfg.codec,
        "spp": cfg.spp,
        "webgl": info.get("renderer", "?"),
        "backend": info.get("backend", "?"),
        "threads": info.get("wasm_threads", cfg.threads),
        "model": str(cfg.model) if cfg.model else "shipped (fp16)",
    }
    totals = {}
    for system, stages in ((GIGAN, GIGAN_STAGES), (CLOUD, CLOUD_STAGES)):
        maps = [m for m in viewer["maps"] if m["system"] == system]
        if not maps:
            raise RuntimeError(f"the page composed no {system} map in {cfg.frames} frames")
        for stage in (*stages, "total"):
            values = [m["total"] if stage == "total" else m["stages"][stage] for m in maps]
            res.add_timing(system=system, scene=scene, metric=stage, samples_s=[v / 1e3 for v in values], **common)
            for m, v in zip(maps, values):
                where = {"frame": m["frame"]} | common
                res.add(system=system, scene=scene, metric=stage, value=v, unit="ms", stat="map", **where)
        totals[system] = float(np.median([m["total"] for m in maps]))
        di = [f[f"{'gigan' if system == GIGAN else 'cloud'}_di"] for f in viewer["frames"]]
        res.add_timing(system=system, scene=scene, metric="di", samples_s=[v / 1e3 for v in di], **common)
        if system == CLOUD:
            hits = sum(bool(m.get("hit")) for m in maps)
            res.add(system=system, scene=scene, metric="hit_rate", value=hits / len(maps), unit="fraction", **common)
    res.add(system="both", scene=scene, metric="total_ratio", value=totals[CLOUD] / totals[GIGAN], unit="x", **common)
    browser, python = viewer["browser_runs_ms"], viewer["python_runs_ms"]
    for runtime, values in (("onnxruntime-web", browser), ("onnxruntime-python", python)):
        where = common | {"runtime": runtime}
        res.add_timing(system=GIGAN, scene=scene, metric="inference_run", samples_s=[v / 1e3 for v in values], **where)
    ratio = float(np.median(browser) / np.median(python)) if browser and python else math.nan
    res.add(system=GIGAN, scene=scene, metric="inference_ratio", value=ratio, unit="x", **common)
    for page_system, stats in canvas_stats(viewer["snapshot"]).items():
        system = GIGAN if page_system == "gigan" else CLOUD
        res.add(system=system, scene=scene, metric="canvas_lit", value=stats["lit"], unit="fraction", **common)
        res.add(system=system, scene=scene, metric="canvas_vs_di", value=stats["vs_di"], unit="tonemapped", **common)
    for name, value in port.items():  # the WebGL2 port against GLRenderer (gicore.gl)
        res.add(system=GIGAN, scene=scene, metric=f"port_{name}", value=value, unit="fraction", **common)
    for stat in ("max", "mean"):
        metric = f"parity_{stat}_abs_diff"
        res.add(system=GIGAN, scene=scene, metric=metric, value=check[stat], unit="tonemapped", **common)


# -- what it shows ------------------------------------------------------------------------------------------
STAGES = ("gi_render", "inference", "transmission", "server", "decode", "warp", "blend", "total")


def stages(rows: Rows) -> list[dict]:
    """The browser-side Table 1: each stage's median over the GI maps, per system; then the shared local DI."""

    def median(system: str, metric: str) -> float | None:
        return next((r["value"] for r in rows if r["system"] == system and matches(r, metric, "median")), None)

    out = [{"stage": s, "gigan": median(GIGAN, s), "cloud": median(CLOUD, s)} for s in STAGES]
    out[-1]["stage"] = "**total**"
    return [
        *out,
        {"stage": "di (local, shared; not counted)", "gigan": median(GIGAN, "di"), "cloud": median(CLOUD, "di")},
    ]


def summary(rows: Rows) -> str:
    """The ratio of totals, the run's settings, the inference comparison and the parity checks."""
    values = {r["metric"]: r["value"] for r in rows if r["stat"] == "value"}
    runs = {r["config"]["runtime"]: r["value"] for r in rows if matches(r, "inference_run", "median")}
    maps = ", ".join(str(int(r["value"])) for r in rows if matches(r, "total", "n"))
    c = rows[0]["config"]
    ports = ", ".join(f"{b} {{port_{b}_rel_diff:.1e}}" for b in PORT_BUFFERS)
    return fill(
        "Cloud baking / GIGAN median total: **{total_ratio:.2f}x** "
        f"({maps} maps; {c['frames']} frames, k = {c['every']}, profile {c['profile']}, {c['store']} store, "
        f"{c['codec']}, {c['spp']} spp). WebGL: {c['webgl']}; onnxruntime-web {c['backend']}, {c['threads']} "
        "threads.\n\nsession.run on the same input: browser {web:.1f} ms, Python onnxruntime {python:.1f} ms "
        "(**{inference_ratio:.2f}x**). Parity with GIModel.predict on the page's G-buffers, tone-mapped: max |Δ| = "
        "{parity_max_abs_diff:.2e}, mean {parity_mean_abs_diff:.2e}. The page's DI + G-buffers against GLRenderer's "
        "at the same GI camera: coverage differs on {port_coverage_mismatch:.1e} of the pixels; mean |Δ| relative to "
        f"the mean: {ports}.",
        values | {"web": runs.get("onnxruntime-web"), "python": runs.get("onnxruntime-python")},
    )


PARTS = (
    Image(SCREENSHOT, "Both canvases and their HUDs", where="dashboard"),
    Table(
        stages,
        (Column("stage (median ms)", "{stage}"), Column("GIGAN", "{gigan:.1f}"), Column("cloud baking", "{cloud:.1f}")),
        notes=summary,
    ),  # fmt: skip
)


BENCH = Bench(
    "web",
    WebBenchConfig,
    measure,
    help="Browser-side Table 1: the Web3D viewer in headless Chromium (Playwright), both systems side by side",
    dashboard=Section("web", "Web3D viewer: browser-side Table 1", 15),
    readme=Block("Web3D viewer, browser-side Table 1", 15),
    parts=PARTS,
    needs=("total", "total_ratio", "parity_max_abs_diff"),
)
