"""Debian's Chromium, headless, driven by Playwright, for the tests that run the Web3D page or onnxruntime-web:
the launching, page opening and waiting are the Web3D package's (:mod:`web3d.headless`, which bench web uses);
:func:`missing` says why such a test cannot run here (its callers skip with that reason); :func:`canvases` reads
both canvases' last frames."""

from __future__ import annotations

import base64
from typing import Any

import numpy as np

from web3d.headless import (  # noqa: F401  (the helpers the browser tests use)
    CHROMIUM,
    NPM_FOLDERS,
    PAGE_TIMEOUT_S,
    SWIFTSHADER,
    SWIFTSHADER_WEBGPU,
    chromium,
    missing,
    viewer_page,
    wait,
)


def canvases(page: Any) -> dict[str, np.ndarray]:
    """Both canvases' last frames as HxWx3 uint8 arrays (``viewer.snapshot()``; the cloud one absent when off)."""
    snap = page.evaluate("window.viewer.snapshot()")
    out = {}
    for system, s in snap.items():
        if s is not None:
            n = int(s["resolution"])
            out[system] = np.frombuffer(base64.b64decode(s["canvas"]), np.uint8).reshape(n, n, 4)[..., :3]
    return out
