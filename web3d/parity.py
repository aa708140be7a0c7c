"""The page against the Python clients it ports (``bench web`` and the page's tests): the browser's prediction against
:class:`gigan_local.inference.GIModel`'s on the same G-buffers (``parity_*``), the WebGL2 port's DI and
G-buffers against :class:`gicore.gl.GLRenderer`'s at the same GI camera (``port_*``), ``session.run`` timed in
the browser and in Python on the same tensor, and what the canvases show (``canvas_*``).
"""

from __future__ import annotations

import base64
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

#: The page's buffers compared with GLRenderer's (:func:`port_check`).
PORT_BUFFERS = ("di", "albedo", "normal", "depth")


def floats(text: str, n: int, channels: int) -> np.ndarray:
    """A base64 float32 buffer of the page as n x n x channels."""
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
        di = np.rint(tonemap(floats(snap["di"], n, 4)[..., :3]) * 255.0) / 255.0
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
    ``session.run`` on the predicted input (the tensor predict encoded), for :func:`time_inference`."""

    def __init__(self, threads: int, scene: str, model: Path | None = None) -> None:
        self.threads, self.scene, self.model = threads, scene, model  # None: the shipped model
        self.diff: dict[str, float] = {}
        self.port: dict[str, float] = {}

    def check(self, parity: dict[str, Any]) -> Callable[[], float]:
        from gicore.tonemap import tonemap
        from gigan_local.inference import DEFAULT_MODEL, GIModel

        n = int(parity["resolution"])
        buffers = {k: floats(parity[k], n, 4)[::-1] for k in ("di", "albedo", "normal", "depth")}
        frame = {k: buffers[k][..., :3] for k in ("di", "albedo", "normal")} | {"depth": buffers["depth"][..., :1]}
        model = GIModel(self.model or DEFAULT_MODEL, threads=self.threads)
        diff = np.abs(tonemap(model.predict(frame)) - floats(parity["display"], n, 3))
        self.diff = {"max": float(diff.max()), "mean": float(diff.mean())}
        self.port = port_check(self.scene, parity, frame)

        def run() -> float:
            t0 = time.perf_counter()
            model.session.run(None, {model.input_name: model._input})  # the input predict encoded
            return time.perf_counter() - t0

        return run


def time_inference(page: Any, python_run: Callable[[], float], runs: int) -> tuple[list[float], list[float]]:
    """``session.run`` on the same input timed ``runs`` times in the page (``viewer.infer()``) and in Python
    (``python_run``: one run, seconds), alternately, so both run under the same load; (browser, python) ms."""
    browser, python = [], []
    for _ in range(runs):
        browser.append(float(page.evaluate("viewer.infer()")))
        python.append(python_run() * 1e3)
    return browser, python
