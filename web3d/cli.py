"""``gigan-web``: export a scene's assets and serve the Web3D viewer (``web3d/static/``) for it, with its
own cloud side: a ``cloudbaking-server`` and a ``network-sim proxy`` per profile in front of it, as child
processes (:mod:`web3d.children`).

    gigan-web --scene lung_plane                          # a cold store; proxies lan, wifi, lte, wan
    gigan-web --scene lung_plane --store gi_store         # a prebaked GI tree (and a cold one on demand)
    gigan-web --scene lung_plane --server http://127.0.0.1:8001   # a server the user runs, no children
    gigan-web --scene lung_plane --no-cloud               # GIGAN alone

then open the printed address in Chrome or Chromium. Its options are derived from :class:`WebConfig`.
"""

from __future__ import annotations

import errno
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import typer

from baseline_cloudbaking.codecs import DEFAULT_CODEC, CodecName
from gicore import option_groups
from gicore.error_policy import UserError, entry_point
from gicore.options import (
    FRAMES,
    HOST_PORT,
    THREADS,
    build_config,
    check_fields,
    config_command,
    split_host_port,
)
from gicore.scene import load_scene
from gigan_local.inference import DEFAULT_MODEL, check_model_option
from network_sim.profiles import profiles_field
from web3d.children import ChildCloud
from web3d.export import export_assets
from web3d.routes_shadow import Shadows
from web3d.serve import WebServer
from web3d.site import WEB_DIR, Site
from web3d.upstreams import OFF, Cloud, Fixed, Unavailable

app = typer.Typer(add_completion=False, help="Serve the Web3D viewer: GIGAN and cloud baking side by side.")
BACKENDS = ("auto", "wasm", "webgpu")


@dataclass(frozen=True)
class WebConfig:
    """One viewer: the scene, where cloud baking answers, and what the page runs."""

    scene: str = option_groups.scene()
    #: URL of a cloud-baking server the user runs (or of a network-sim proxy in front of it), which the page talks to
    #: as profile 'direct'; absent: gigan-web starts its own server and proxies.
    server: str | None = field(default=None, metadata={"conflicts": ("store", "profiles")})
    #: Cloud baking beside GIGAN (--no-cloud: GIGAN alone, no server started).
    cloud: bool = True
    #: GI-tree folder the started server serves (a prebaked or an earlier run's); the page may also pick a cold
    #: store (a second server, started on demand). Absent: an empty temporary store, the only one.
    store: Path | None = None
    profiles: tuple[str, ...] = profiles_field(
        note="of the proxies started in front of the server; the first is the page's default"
    )
    #: HOST:PORT to serve the page on (port 0: any free port; the address is printed).
    listen: str = field(default="127.0.0.1:8080", metadata=HOST_PORT)
    #: Frames of the fly-through the page plays (then it stops and shows the medians).
    frames: int = field(default=120, metadata=FRAMES)
    orbit_frames: int = option_groups.orbit_frames()
    every: int = option_groups.every(10, note="both systems make or fetch one")
    #: Eq. 1's tau: the DI weight of the blend (0: the warped GI map alone, as the Python clients default).
    tau: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})
    #: GI-map codec the cloud side asks for (jpeg, webp and png decode with createImageBitmap).
    codec: CodecName = DEFAULT_CODEC
    spp: int = option_groups.spp(note="of the maps the cloud side asks for")
    #: onnxruntime-web backend: webgpu when the browser has it (auto), or one of them.
    backend: Literal[BACKENDS] = "auto"  # type: ignore[valid-type]
    #: onnxruntime-web wasm threads (GIModel's default in Python is 2).
    threads: int = field(default=2, metadata=THREADS)
    seed: int = option_groups.seed(note="the camera path")
    #: Folder for the exported assets (default: .cache/web3d/SCENE in the working folder).
    assets: Path | None = None
    #: ONNX model the page runs (a gigan-export output, its model.json beside it); absent: the shipped fp16 model.
    model: Path | None = None

    def __post_init__(self) -> None:
        check_fields(self)
        split_host_port(self.listen, "--listen")  # before anything is exported
        if self.server is not None and not self.server.startswith(("http://", "https://")):
            raise UserError(
                f"--server {self.server!r} is not an http(s) URL", "give e.g. --server http://127.0.0.1:8001"
            )
        if self.model is not None:
            check_model_option(self.model)
        if self.codec in ("exr-half", "zstd-f16"):
            raise UserError(f"--codec {self.codec}: the page decodes 8-bit images only", "pick jpeg, webp or png")
        self._check_cloud()

    def _check_cloud(self) -> None:
        if not self.cloud and (self.store is not None or self.server is not None):
            option = "--store" if self.store is not None else "--server"
            raise UserError(f"{option} and --no-cloud conflict: --no-cloud turns the cloud side off", "drop one")
        if self.store is not None and not self.store.is_dir():
            raise UserError(
                f"--store {self.store} is not a folder",
                "give a GI-tree folder (cloudbaking-prebake --store), or leave --store out for a cold store",
            )

    def page_config(self, resolution: int) -> dict[str, Any]:
        """What ``/config.json`` tells the page."""
        keys = ("scene", "frames", "every", "tau", "codec", "spp", "backend", "threads")
        return {k: v for k, v in asdict(self).items() if k in keys} | {"resolution": resolution}


def cloud_for(cfg: WebConfig, report: Callable[[str], None] = typer.echo, logs: Path | None = None) -> Cloud:
    """The cloud side ``cfg`` asks for: none, the user's server, or children (started when it is entered;
    ``report`` gets a line per child; ``logs``: a folder for the proxies' per-chunk logs, see ChildCloud)."""
    if not cfg.cloud:
        return OFF
    if cfg.server is not None:
        return Fixed.direct(cfg.server)
    scenes = Path(cfg.scene).resolve().parent if Path(cfg.scene).suffix else None  # a spec file's folder
    return ChildCloud(cfg.profiles, cfg.store, scenes, cfg.seed, report, logs)


def prepare(cfg: WebConfig, cloud: Cloud) -> Site:
    """Export the assets of ``cfg.scene`` (into ``cfg.assets``) and describe the site serving them with
    ``cloud`` (:func:`cloud_for`)."""
    if not (WEB_DIR / "node_modules" / "onnxruntime-web").is_dir():
        raise UserError(f"{WEB_DIR}/node_modules is missing", "run `make setup` (npm ci in web3d/static/)")
    spec = load_scene(cfg.scene)
    assets = cfg.assets or Path(".cache") / "web3d" / spec.name
    model = cfg.model or DEFAULT_MODEL
    header = export_assets(
        cfg.scene, assets, frames=cfg.frames, orbit_frames=cfg.orbit_frames, seed=cfg.seed, model=model
    )
    config = cfg.page_config(header["resolution"]) | {"scene": spec.name}
    return Site(assets.resolve(), config, cloud, Shadows(spec, header["shadow_size"]))


def serve_command(given: dict[str, Any]) -> None:
    """Export the scene's assets, start the cloud side and serve the page until SIGINT or SIGTERM (a service: a
    stop exits 0, its children stopped)."""
    cfg = build_config(WebConfig, given)
    host, port = split_host_port(cfg.listen, "--listen")
    try:
        server = WebServer(None, host, port)  # the address first: a taken port fails before anything is written
    except OSError as exc:
        taken = exc.errno in (errno.EADDRINUSE, errno.EACCES)  # in use, or a privileged port
        todo = "pick a free port (0 picks one)" if taken else "give an address of this machine, e.g. 127.0.0.1:8080"
        raise UserError(f"--listen {cfg.listen}: cannot listen ({exc.strerror or exc})", todo) from None
    cloud = cloud_for(cfg)
    site = prepare(cfg, cloud)  # rewritten whole on every start, so one cut short by a stop is simply redone
    with _started(cloud):
        server.attach(site)
        line = f"serving {site.config['scene']} at {server.url}/ ({_describe(cfg, cloud)})"
        server.serve_forever(lambda: typer.echo(line))


@contextmanager
def _started(cloud: Cloud) -> Iterator[None]:
    """``cloud``'s children running for the body; a child that does not start is one error line (the others
    are stopped)."""
    with ExitStack() as children:
        try:
            children.enter_context(cloud)
        except Unavailable as exc:
            raise UserError(str(exc), "see its message; check --store and --scene") from None
        yield


def _describe(cfg: WebConfig, cloud: Cloud) -> str:
    if not cloud.profiles:
        return "cloud baking: off"
    if cfg.server is not None:
        return f"cloud baking: {cfg.server}"
    return f"cloud baking: profiles {', '.join(cloud.profiles)}; stores {', '.join(cloud.stores)}"


config_command(app, WebConfig, serve_command)  # computes the options' defaults (reads the profiles' traces)
main = entry_point(app, services=True)

if __name__ == "__main__":
    main()
