"""``gigan-web``: export a scene's assets and serve the Web3D viewer (``web3d/static/``) for it.

    gigan-web --scene lung_plane --server http://127.0.0.1:8001      # the URL of cloudbaking-server or of
                                                                     # the network-sim proxy in front of it

then open the printed address in Chrome or Chromium. Its options are derived from :class:`WebConfig`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import typer

from baseline_cloudbaking.codecs import CODEC_NAMES, DEFAULT_CODEC
from gicore.error_policy import UserError, entry_point, serving
from gicore.options import (
    FRAMES,
    HOST_PORT,
    SEED,
    SPP,
    THREADS,
    build_config,
    check_fields,
    config_command,
    split_host_port,
)
from gicore.scene import load_scene
from gigan_local.inference import DEFAULT_MODEL, check_model_option
from web3d.export import export_assets
from web3d.serve import WEB_DIR, Site, WebServer

app = typer.Typer(add_completion=False, help="Serve the Web3D viewer: GIGAN and cloud baking side by side.")
BACKENDS = ("auto", "wasm", "webgpu")
CodecName = Literal[CODEC_NAMES]  # type: ignore[valid-type]


@dataclass(frozen=True)
class WebConfig:
    """One viewer: the scene, where cloud baking answers, and what the page runs."""

    #: Scene name or spec file.
    scene: str = "lung_plane"
    #: URL of the cloud-baking server, or of the network-sim proxy in front of it; absent: the cloud side is off.
    server: str | None = None
    #: HOST:PORT to serve the page on (port 0: any free port; the address is printed).
    listen: str = field(default="127.0.0.1:8080", metadata=HOST_PORT)
    #: Frames of the fly-through the page plays (then it stops and shows the medians).
    frames: int = field(default=120, metadata=FRAMES)
    #: Frames per full orbit of the camera path.
    orbit_frames: int = field(default=300, metadata=FRAMES)
    #: GI-map period k: both systems make or fetch a new GI map every k frames.
    every: int = field(default=10, metadata=FRAMES)
    #: Eq. 1's tau: the DI weight of the blend (0: the warped GI map alone, as the Python clients default).
    tau: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})
    #: GI-map codec the cloud side asks for (jpeg, webp and png decode with createImageBitmap).
    codec: CodecName = DEFAULT_CODEC
    #: Path-tracing samples per pixel the cloud side asks for.
    spp: int = field(default=64, metadata=SPP)
    #: onnxruntime-web backend: webgpu when the browser has it (auto), or one of them.
    backend: Literal[BACKENDS] = "auto"  # type: ignore[valid-type]
    #: onnxruntime-web wasm threads (GIModel's default in Python is 2).
    threads: int = field(default=2, metadata=THREADS)
    #: Seed of the camera path.
    seed: int = field(default=0, metadata=SEED)
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

    def page_config(self, resolution: int) -> dict[str, Any]:
        """What ``/config.json`` tells the page."""
        keys = ("scene", "frames", "every", "tau", "codec", "spp", "backend", "threads")
        return {k: v for k, v in asdict(self).items() if k in keys} | {
            "cloud": self.server is not None,
            "resolution": resolution,
        }


def prepare(cfg: WebConfig) -> Site:
    """Export the assets of ``cfg.scene`` (into ``cfg.assets``) and describe the site serving them."""
    if not (WEB_DIR / "node_modules" / "onnxruntime-web").is_dir():
        raise UserError(f"{WEB_DIR}/node_modules is missing", "run `make setup` (npm ci in web3d/static/)")
    spec = load_scene(cfg.scene)
    assets = cfg.assets or Path(".cache") / "web3d" / spec.name
    model = cfg.model or DEFAULT_MODEL
    header = export_assets(
        cfg.scene, assets, frames=cfg.frames, orbit_frames=cfg.orbit_frames, seed=cfg.seed, model=model
    )
    return Site(assets.resolve(), cfg.page_config(header["resolution"]) | {"scene": spec.name}, cfg.server)


def serve_command(given: dict[str, Any]) -> None:
    """Export the scene's assets and serve the page until SIGINT or SIGTERM (a service: a stop exits 0)."""
    with serving():
        cfg = build_config(WebConfig, given)
        host, port = split_host_port(cfg.listen, "--listen")
        try:
            server = WebServer(None, host, port)  # the address first: a taken port fails before anything is written
        except OSError as exc:
            raise UserError(
                f"--listen {cfg.listen}: cannot listen ({exc.strerror or exc})", "pick a free port"
            ) from None
        site = prepare(cfg)  # rewritten whole on every start, so one cut short by a stop is simply redone
        server.attach(site)
        typer.echo(f"serving {site.config['scene']} at {server.url}/ (cloud baking: {cfg.server or 'off'})")
        server.serve_forever()


config_command(app, WebConfig, serve_command)
main = entry_point(app)

if __name__ == "__main__":
    main()
