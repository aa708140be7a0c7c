"""Debian's Chromium, headless, driven by Playwright, for the tests that run the Web3D page or onnxruntime-web:
software WebGL2 (SwiftShader through ANGLE) and, where asked, SwiftShader's WebGPU adapter. :func:`missing` says
why such a test cannot run here (its callers skip with that reason)."""

from __future__ import annotations

import base64
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from web3d.serve import WEB_DIR

CHROMIUM = Path("/usr/bin/chromium")
#: Chromium's software WebGL2, for a machine without a GPU.
SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
#: Also SwiftShader's WebGPU adapter (onnxruntime-web's WebGPU back end, in software).
SWIFTSHADER_WEBGPU = [*SWIFTSHADER, "--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"]
#: The npm folders the page imports (``make setup`` runs npm ci in web3d/static/).
NPM_FOLDERS = ("onnxruntime-web/dist", "fzstd/esm", "three/build", "three/examples/jsm")
#: Seconds the page may take to load, or to do one step a test asks of it, on 2 busy cores (a hang guard).
PAGE_TIMEOUT_S = 300.0


def missing() -> str | None:
    """Why a browser test cannot run here (no Chromium, no Playwright, no npm packages), or None."""
    if not CHROMIUM.is_file():
        return f"{CHROMIUM} is missing (apt-get install chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright is not installed (pip install -e '.[test]')"
    absent = [f for f in NPM_FOLDERS if not (WEB_DIR / "node_modules" / f).is_dir()]
    if absent:
        return f"{WEB_DIR}/node_modules lacks {absent[0]} (make setup runs npm ci in web3d/static/)"
    return None


@contextmanager
def chromium(flags: list[str] = SWIFTSHADER) -> Iterator[Any]:
    """A headless Chromium (a Playwright Browser), closed after."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=flags)
        try:
            yield browser
        finally:
            browser.close()


@contextmanager
def viewer_page(url: str, query: str = "") -> Iterator[Any]:
    """The Web3D page at ``url/?query`` in a new headless Chromium, once ``window.viewer.ready``; a page error
    raises RuntimeError with the page's message. The page records its uncaught errors in ``page.errors``."""
    with chromium() as browser:
        page = browser.new_page(viewport={"width": 1200, "height": 1000}, accept_downloads=True)
        page.errors = []
        page.on("pageerror", lambda e: page.errors.append(str(e)))
        page.goto(f"{url}/{'?' + query if query else ''}")
        wait(page, "window.viewer && (window.viewer.ready || window.viewer.error)")
        yield page


def wait(page: Any, expression: str, arg: Any = None, timeout_s: float = PAGE_TIMEOUT_S) -> Any:
    """Wait until ``expression`` (a JS expression, or a function of ``arg``) is truthy in the page; raise with
    the page's error when it has one."""
    handle = page.wait_for_function(expression, arg=arg, timeout=timeout_s * 1e3, polling=50)
    error = page.evaluate("window.viewer && window.viewer.error") or (page.errors[0] if page.errors else None)
    if error:
        raise RuntimeError(f"the viewer failed: {error}")
    return handle.json_value()


def canvases(page: Any) -> dict[str, np.ndarray]:
    """Both canvases' last frames as HxWx3 uint8 arrays (``viewer.snapshot()``; the cloud one absent when off)."""
    snap = page.evaluate("window.viewer.snapshot()")
    out = {}
    for system, s in snap.items():
        if s is not None:
            n = int(s["resolution"])
            out[system] = np.frombuffer(base64.b64decode(s["canvas"]), np.uint8).reshape(n, n, 4)[..., :3]
    return out
