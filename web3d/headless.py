"""The Web3D page in headless Chromium (Playwright), as ``bench web`` and the browser tests drive it: launching
Debian's Chromium with software or GPU WebGL, serving a site (:func:`served_page`) and opening the page once
``window.viewer`` is ready, waiting on it, and replaying a path file through ``viewer.replay`` (the camera API the
page's controls drive: each path frame moves the controls, as a person's drag would, one per drawn frame) behind
a chosen network profile.

A replay starts settled at its first view (both panes' maps made there, nothing in flight) and ends settled at its
last: its frames are every frame drawn in between, the path's own and those that land the last maps. The page
keeps only its last few thousand frame and map records (``viewer.frames``, ``viewer.maps``): an open page's
:class:`Records` reads them as they come, whenever :func:`wait` and :func:`settle` wait on it.
docs/architecture.md, Web3D viewer and bench web.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from web3d.site import Site

CHROMIUM = Path("/usr/bin/chromium")
#: Chromium's software WebGL2 (SwiftShader through ANGLE), for a machine without a GPU.
SWIFTSHADER = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
#: Also SwiftShader's WebGPU adapter (onnxruntime-web's WebGPU back end runs, in software: a functional check).
SWIFTSHADER_WEBGPU = [*SWIFTSHADER, "--enable-unsafe-webgpu", "--use-webgpu-adapter=swiftshader"]
#: Chromium's flags per ``--webgl`` choice; ``gpu``: the GPU through ANGLE's Vulkan back end, with WebGPU.
WEBGL_FLAGS = {
    "swiftshader": SWIFTSHADER,
    "swiftshader_webgpu": SWIFTSHADER_WEBGPU,
    "gpu": ["--use-angle=vulkan", "--enable-features=Vulkan", "--ignore-gpu-blocklist", "--enable-unsafe-webgpu"],
}
#: The npm folders the page imports (``make setup`` runs npm ci in web3d/static/).
NPM_FOLDERS = ("onnxruntime-web/dist", "fzstd/esm", "three/build", "three/examples/jsm")
#: Seconds the page may take to load, or to do one step asked of it, on 2 busy cores (a hang guard).
PAGE_TIMEOUT_S = 300.0
#: Seconds between two reads of the page's records while waiting on it: the page keeps its last 4096 frames
#: (loop.js, FRAMES_KEPT), over a minute at 60 frames a second.
PULL_EVERY_S = 1.0
#: The page's frame and map records from the given indices on (none while the page loads).
PULL = """([f, m]) => window.viewer?.frames ? { frames: viewer.frames.since(f), maps: viewer.maps.since(m) }
  : { frames: [], maps: [] }"""
#: True once a whole tick of the page's frame loop has passed drawing nothing with no map in flight: nothing is
#: due, so nothing will be drawn until something changes (the frame loop draws a tick only when something is new).
SETTLED = """async () => {
  const n = viewer.frames.count;
  await new Promise((resolve) => requestAnimationFrame(() => requestAnimationFrame(resolve)));
  const f = viewer.frames.last();
  return Boolean(viewer.error) || (viewer.frames.count === n && f !== undefined && !f.gigan.inflight
    && !(f.cloud && f.cloud.inflight));
}"""
#: Start a replay; ``window.benchReplay`` says when it has finished or failed.
START_REPLAY = """doc => {
  window.benchReplay = { done: false, error: null };
  viewer.replay(doc).then(() => (window.benchReplay.done = true), (e) => (window.benchReplay.error = String(e)));
}"""


class Records:
    """Every frame the page drew and every GI map it made since it loaded, in order (``frames[i]`` is the page's
    frame ``i``), read from the page's bounded records by :meth:`pull`."""

    def __init__(self) -> None:
        self.frames: list[dict[str, Any]] = []
        self.maps: list[dict[str, Any]] = []

    def pull(self, page: Any) -> None:
        """Read the records the page added since the last pull (the page raises once some were dropped unread)."""
        new = page.evaluate(PULL, [len(self.frames), len(self.maps)])
        self.frames += new["frames"]
        self.maps += new["maps"]


def missing() -> str | None:
    """Why the page cannot run here (no Chromium, no Playwright, no npm packages), or None."""
    from web3d.site import WEB_DIR

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
def viewer_page(url: str, query: str = "", flags: list[str] = SWIFTSHADER) -> Iterator[Any]:
    """The Web3D page at ``url/?query`` in a new headless Chromium, once ``window.viewer.ready``; a page error
    raises RuntimeError with the page's message. The page's uncaught errors are kept in ``page.errors``, its console
    errors (a request that failed among them, the browser's own too) in ``page.console_errors``, its records as
    they are read in ``page.records`` (:class:`Records`)."""
    with chromium(flags) as browser:
        page = browser.new_page(viewport={"width": 1200, "height": 1000}, accept_downloads=True)
        page.errors, page.console_errors, page.records = [], [], Records()
        page.on("pageerror", lambda e: page.errors.append(str(e)))
        page.on("console", lambda m: page.console_errors.append(m.text) if m.type == "error" else None)
        page.goto(f"{url}/{'?' + query if query else ''}")
        wait(page, "window.viewer && (window.viewer.ready || window.viewer.error)")
        yield page


@contextmanager
def served_page(site: Site, query: str = "", flags: list[str] = SWIFTSHADER) -> Iterator[tuple[str, Any]]:
    """``site``'s cloud side started, ``site`` served on a free loopback port (:class:`web3d.serve.WebServer`) and
    the page open there (:func:`viewer_page`): (the site's URL, the page); all stopped after."""
    from web3d.serve import WebServer

    with site.cloud, WebServer(site) as web, viewer_page(web.url, query, flags) as page:
        yield web.url, page


def wait(page: Any, expression: str, arg: Any = None, timeout_s: float = PAGE_TIMEOUT_S) -> Any:
    """Wait until ``expression`` (a JS expression, or a function of ``arg``) is truthy in the page, reading its
    records meanwhile (:data:`PULL_EVERY_S`); raise with the page's error when it has one."""
    from playwright.sync_api import TimeoutError as PageTimeout

    deadline = time.monotonic() + timeout_s
    while True:
        page.records.pull(page)
        left_s = deadline - time.monotonic()
        slice_ms = max(min(left_s, PULL_EVERY_S), 1e-3) * 1e3
        try:
            handle = page.wait_for_function(expression, arg=arg, timeout=slice_ms, polling=50)
            break
        except PageTimeout:
            if left_s <= PULL_EVERY_S:
                raise
    page.records.pull(page)
    error = page.evaluate("window.viewer && window.viewer.error") or (page.errors[0] if page.errors else None)
    if error:
        raise RuntimeError(f"the viewer failed: {error}")
    return handle.json_value()


def settle(page: Any, timeout_s: float = PAGE_TIMEOUT_S) -> None:
    """Wait until the page has drawn a frame and has nothing in flight or due (:data:`SETTLED`)."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(SETTLED):
        page.records.pull(page)
        if time.monotonic() > deadline:
            raise TimeoutError(f"the viewer did not settle within {timeout_s:g} s")
    wait(page, "true")  # raises with the page's error, if it has one


@dataclass(frozen=True)
class Segment:
    """One replay's share of the page's records: ``page.records.frames[frames[0]:frames[1]]`` and its ``maps``
    likewise, behind network ``profile``."""

    profile: str
    frames: tuple[int, int]
    maps: tuple[int, int]


def counts(page: Any) -> tuple[int, int]:
    """The frames drawn and the maps made so far (all of them read into ``page.records``)."""
    page.records.pull(page)
    return len(page.records.frames), len(page.records.maps)


def replay(
    page: Any, doc: dict[str, Any], profile: str, timeout_s: float = PAGE_TIMEOUT_S, shot: Path | None = None
) -> Segment:
    """Replay the path file ``doc`` behind ``profile``: the profile chosen and the camera and light put at the
    path's first frame (a fresh map from each pane there), settled, then the path played one frame per drawn
    frame and settled again (module docstring). ``shot``: a screenshot of the page there once the path's last
    frame is drawn (before settling: the maps shown are a few frames old, warped to it)."""
    first = doc["frames"][0]
    drawn = counts(page)[0]
    page.evaluate(
        "([profile, f]) => { viewer.setProfile(profile); viewer.setCamera(f.camera); viewer.setLight(f.light); }",
        [profile, first],
    )
    wait(page, "n => viewer.frames.count > n", drawn, timeout_s)
    settle(page, timeout_s)
    frames0, maps0 = counts(page)
    page.evaluate(START_REPLAY, doc)
    wait(page, "window.benchReplay.done || window.benchReplay.error", None, timeout_s)
    error = page.evaluate("window.benchReplay.error")
    if error:
        raise RuntimeError(f"the viewer's replay failed: {error}")
    if shot is not None:
        page.locator("#viewer").screenshot(path=str(shot))
    settle(page, timeout_s)
    frames1, maps1 = counts(page)
    return Segment(profile, (frames0, frames1), (maps0, maps1))
