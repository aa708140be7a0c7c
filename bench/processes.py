"""The processes of the client benches (`bench latency`, `bench prefetch`, `bench service`): a cloud-baking server,
network proxies and client runs, each pinned to its cores (:func:`pinning`), and the first pass along a camera
path that fills (or warms up) a server's GI tree.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np

if TYPE_CHECKING:
    from gicore.results import Results
    from gicore.scene import SceneSpec

#: The console scripts of this environment.
BIN = Path(sys.executable).parent


def pinning(enabled: bool) -> dict[str, Any]:
    """Cores of the server, the proxy and the clients (``taskset -c``): with 2 cores the server and the
    proxy share one and the clients get the other; with more the proxy gets one, the server about half
    of the rest and the clients the others. ``method`` is ``none`` (with the reason) when not pinned."""
    cores = sorted(os.sched_getaffinity(0))
    if not enabled:
        return {"method": "none", "reason": "--no-pin", "cores": cores}
    if shutil.which("taskset") is None:
        return {"method": "none", "reason": "taskset (util-linux) is not installed", "cores": cores}
    if len(cores) < 2:
        return {"method": "none", "reason": "one core: every process shares it", "cores": cores}
    if len(cores) == 2:
        roles = {"server": cores[:1], "proxy": cores[:1], "client": cores[1:]}
    else:
        split = 1 + (len(cores) - 1) // 2
        roles = {"proxy": cores[:1], "server": cores[1:split], "client": cores[split:]}
    return {"method": "taskset -c", "cores": cores} | roles


@contextmanager
def client_cores(plan: dict[str, Any]) -> Iterator[None]:
    """Run this thread (and the threads it starts) on the plan's client cores, then restore."""
    if plan["method"] == "none":
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, plan["client"])
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


class RunPlace(NamedTuple):
    """Where a client bench's run happens."""

    #: The scene the clients fly through.
    spec: SceneSpec
    #: The folder of its spec file, which the server is given (None for a built-in scene).
    scenes_dir: Path | None
    #: The run's work folder under its output folder (created).
    work: Path
    #: The core plan (:func:`pinning`), also recorded in the provenance's ``settings.pinning``.
    plan: dict[str, Any]


def run_place(scene: str, res: Results, folder: str, pin: bool) -> RunPlace:
    """The :class:`RunPlace` of a run of ``scene`` working in ``res.out / folder``."""
    from gicore.scene import load_scene

    work = res.out / folder
    work.mkdir(parents=True, exist_ok=True)
    res.settings["pinning"] = plan = pinning(pin)
    return RunPlace(load_scene(scene), scene_folder(scene), work, plan)


def scene_folder(scene: str) -> Path | None:
    """The folder of ``scene``'s spec file, which a server is given (None for a built-in scene)."""
    return Path(scene).resolve().parent if Path(scene).suffix else None


def check_served(resolution: int) -> None:
    """Refuse, before any process starts, a map resolution the benches' servers would not serve (their settings:
    the defaults, or CLOUDBAKING_RESOLUTIONS of this environment, which they inherit)."""
    from baseline_cloudbaking.server.settings import Settings
    from gicore.error_policy import UserError

    served = Settings().resolutions
    if resolution not in served:
        raise UserError(
            f"--resolution {resolution} is not served by cloudbaking-server",
            f"use one of {', '.join(map(str, served))}",
        )


def taskset(plan: dict[str, Any], role: str) -> list[str]:
    """The command prefix that pins a process of ``role`` as ``plan`` says (empty when not pinned)."""
    return ["taskset", "-c", ",".join(map(str, plan[role]))] if plan["method"] != "none" else []


def threads(plan: dict[str, Any], role: str) -> int:
    """The cores a process of ``role`` may use."""
    return len(plan[role]) if plan["method"] != "none" else len(plan["cores"])


@contextmanager
def pinned_server(plan: dict[str, Any], store: Path, scenes_dir: Path | None, *options: str) -> Iterator[str]:
    """A pinned ``cloudbaking-server`` (:func:`web3d.children.start_server`) given ``options`` besides; yields
    its base URL."""
    from web3d.children import start_server, url

    env = ["env", f"CLOUDBAKING_RENDER_THREADS={threads(plan, 'server')}"]
    with start_server(store, scenes_dir, *options, prefix=[*env, *taskset(plan, "server")]) as server:
        yield url(server)


@contextmanager
def pinned_proxy(plan: dict[str, Any], profile: str, upstream: str, seed: int) -> Iterator[str]:
    """A pinned ``network-sim proxy --profile`` in front of ``upstream`` (a URL); yields the proxy's URL."""
    from network_sim.process import proxy
    from web3d.children import url

    host, _, port = upstream.removeprefix("http://").rpartition(":")
    args = ("--profile", profile, "--seed", str(seed))
    with proxy((host, int(port)), *args, timeout=60.0, prefix=taskset(plan, "proxy")) as running:
        yield url(running)


def run_client(plan: dict[str, Any], argv: list[str], out: Path, timeout_s: float) -> Path:
    """Run a pinned client process writing into ``out`` (a fresh folder; its stdout and stderr kept in
    ``console.txt``); its output folder."""
    shutil.rmtree(out, ignore_errors=True)
    proc = subprocess.run(
        [*taskset(plan, "client"), *argv, "--out", str(out)], capture_output=True, text=True, timeout=timeout_s
    )
    if out.is_dir():
        (out / "console.txt").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"{Path(argv[0]).name} exited with {proc.returncode}:\n{proc.stderr[-3000:]}")
    return out


class PathRun(Protocol):
    """What :func:`ask_path` reads of a bench's config (``LatencyConfig``, ``PrefetchConfig``)."""

    resolution: int
    codec: str
    spp: int
    frames: int
    orbit_frames: int
    path: Path | None
    read_timeout_s: float


def with_path_frames(cfg: Any, spec: SceneSpec) -> Any:
    """``cfg`` with ``frames`` the count of its ``path`` file (checked against ``spec``: one error line before
    any process starts); ``cfg`` itself without one."""
    from gicore.path_file import read_path_file

    return cfg if cfg.path is None else replace(cfg, frames=len(read_path_file(cfg.path, spec).frames))


def path_options(cfg: PathRun) -> list[str]:
    """A client's options for the path of ``cfg``: its path file, else the scripted path's frames and lap."""
    if cfg.path is not None:
        return ["--path", str(cfg.path)]
    return ["--frames", str(cfg.frames), "--orbit-frames", str(cfg.orbit_frames)]


def ask_path(
    url: str, scene: str, cfg: PathRun, seed: int, *, residual: bool = False, off_path: bool = False
) -> dict[str, int]:
    """Ask ``url`` directly for the GI camera of every frame of the path (its ``path`` file, else the scripted
    one from ``seed``), one request at a time (``off_path``: for one camera one unit above the first, which no
    path frame is within tolerance of: it compiles the server's scene and passes and stores nothing a run
    would hit); returns the hit and miss counts."""
    from baseline_cloudbaking.client import RemoteConfig, RemoteSource
    from gicore.path_file import flown_path
    from gicore.scene import load_scene

    spec = load_scene(scene)
    timeout = cfg.read_timeout_s
    remote = RemoteConfig(url, Path(scene).stem, cfg.resolution, cfg.codec, cfg.spp, residual, spec.light.moves,
                          read_timeout_s=timeout, deadline_s=2 * timeout, retry_after_s=0.0)  # fmt: skip
    views = flown_path(spec, cfg, seed).views(cfg.resolution)[: 1 if off_path else None]
    with RemoteSource(remote) as source:
        for frame, (camera, light) in enumerate(views):
            gi_camera = camera.with_fov(spec.camera.gi_fov)
            if off_path:
                gi_camera = replace(gi_camera, origin=tuple(np.add(camera.origin, (0.0, 1.0, 0.0))))
            source.request(gi_camera, light, frame)
            source.wait(2 * timeout + 10)
    failed = [r for r in source.records if r["status"] != "ok"]
    if failed:
        raise RuntimeError(f"the server at {url} failed a request: {failed[0]['status']}: {failed[0]['error']}")
    hits = sum(int(r["hit"]) for r in source.records)
    return {"hits": hits, "misses": len(source.records) - hits}
