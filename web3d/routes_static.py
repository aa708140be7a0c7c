"""The page's files: ``/`` (``index.html``) and ``/js/...`` from ``web3d/static/``, ``/npm/...`` from the npm
packages' distribution folders, ``/assets/...`` the exported files, and nothing else.

Starlette's :class:`~starlette.staticfiles.StaticFiles` answers GET and HEAD with ``ETag`` and
``Last-Modified`` and 304 when the browser's copy is current, and refuses paths out of its folder, with NUL
bytes or too long. Each folder here also has an allow-list: no dotfile anywhere, no ``package.json`` or
lockfile, and of an ``--assets`` folder that held other files before only the exported ones. npm files change
only with ``npm ci``, so the browser keeps them a day; the page and the assets, which change with every edit or
export, it revalidates on every load (``no-cache``: a 304 costs a round trip, not the file).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path, PurePosixPath

from starlette.exceptions import HTTPException
from starlette.responses import Response
from starlette.routing import BaseRoute, Mount, Route
from starlette.staticfiles import PathLike, StaticFiles
from starlette.types import Scope

#: The exported files the page loads (web3d.export), relative to the assets folder.
ASSET_FILES = frozenset(
    {"scene.json", "shaders.json", "scene.bin", "path.json", "model/model.onnx", "model/model.json"}
)
#: npm folders the page imports, by URL prefix: only these folders of ``web3d/static/node_modules`` are served.
NPM_ROOTS = {
    "/npm/onnxruntime-web": "onnxruntime-web/dist",
    "/npm/fzstd": "fzstd/esm",
    "/npm/three/build": "three/build",
    "/npm/three/examples/jsm": "three/examples/jsm",
}
#: Files never served from any folder.
HIDDEN_NAMES = frozenset({"package.json", "package-lock.json", "node_modules"})
REVALIDATE = "no-cache"
NPM_CACHE = "public, max-age=86400"


def visible(path: str) -> bool:
    """Whether a folder's file at ``path`` (StaticFiles' normalised relative path) may be served."""
    parts = PurePosixPath(path).parts
    return not any(part.startswith(".") or part in HIDDEN_NAMES for part in parts)


class Files(StaticFiles):
    """StaticFiles serving only the paths ``allowed`` accepts, each with ``cache_control``."""

    def __init__(self, directory: Path, allowed: Callable[[str], bool], cache_control: str):
        super().__init__(directory=directory, check_dir=False)
        self.allowed = allowed
        self.cache_control = cache_control

    async def get_response(self, path: str, scope: Scope) -> Response:
        if not self.allowed(path):
            raise HTTPException(status_code=404)
        return await super().get_response(path, scope)

    def file_response(
        self, full_path: PathLike, stat_result: os.stat_result, scope: Scope, status_code: int = 200
    ) -> Response:
        response = super().file_response(full_path, stat_result, scope, status_code)
        response.headers["Cache-Control"] = self.cache_control  # on a 304 too, which refreshes the browser's copy
        return response


class Page(Files):
    """The page itself, ``index.html``, at whatever path it is routed to."""

    def __init__(self, web: Path) -> None:
        super().__init__(web, "index.html".__eq__, REVALIDATE)

    def get_path(self, scope: Scope) -> str:
        return "index.html"


def routes(assets: Path, web: Path) -> list[BaseRoute]:
    """The static routes: the page (``/``, ``/index.html``), its modules, the npm folders and the assets."""
    page = Page(web)
    files: list[BaseRoute] = [Route(path, page, methods=["GET", "HEAD"]) for path in ("/", "/index.html")]
    files.append(Mount("/js", Files(web / "js", visible, REVALIDATE)))
    files += [Mount(url, Files(web / "node_modules" / path, visible, NPM_CACHE)) for url, path in NPM_ROOTS.items()]
    files.append(Mount("/assets", Files(assets, ASSET_FILES.__contains__, REVALIDATE)))
    return files
