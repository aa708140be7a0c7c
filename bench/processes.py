"""The processes of the client benches (`bench latency`, `bench prefetch`, `bench service`, `bench load`, `bench web`):
a cloud-baking server, network proxies and client runs, each pinned to its cores (:func:`gicore.cores.pinning`).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from gicore.cores import pinning, taskset, threads

if TYPE_CHECKING:
    from baseline_cloudbaking.client import PathRequests
    from gicore.path_file import PathFile
    from gicore.results import Results
    from gicore.scene import SceneSpec

#: The console scripts of this environment.
BIN = Path(sys.executable).parent


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
    #: The run's path file, read and checked against the scene (None: the scripted path).
    flown: PathFile | None


def run_place(scene: str, res: Results, folder: str, pin: bool, path: Path | None = None) -> RunPlace:
    """The :class:`RunPlace` of a run of ``scene`` working in ``res.out / folder``, flying the path file ``path``
    (read first: a refused one leaves no folder)."""
    from gicore.path_file import read_path_file
    from gicore.scene import load_scene

    spec = load_scene(scene)
    flown = None if path is None else read_path_file(path, spec)
    work = res.out / folder
    work.mkdir(parents=True, exist_ok=True)
    res.settings["pinning"] = plan = pinning(pin)
    return RunPlace(spec, scene_folder(scene), work, plan, flown)


def scene_folder(scene: str) -> Path | None:
    """The folder of ``scene``'s spec file, which a server is given (None for a built-in scene)."""
    return Path(scene).resolve().parent if Path(scene).suffix else None


@contextmanager
def pinned_server(plan: dict[str, Any], store: Path, scenes_dir: Path | None, *options: str) -> Iterator[str]:
    """A pinned ``cloudbaking-server`` (:func:`web3d.children.start_server`) given ``options`` besides; yields
    its base URL."""
    from web3d.children import start_server, url

    env = ["env", f"CLOUDBAKING_RENDER_THREADS={threads(plan, 'server')}"]
    with start_server(store, scenes_dir, *options, prefix=[*env, *taskset(plan, "server")]) as server:
        yield url(server)


@contextmanager
def pinned_proxy(
    plan: dict[str, Any], profile: str, upstream: str, seed: int, lateness: Path | None = None
) -> Iterator[str]:
    """A pinned ``network-sim proxy --profile`` in front of ``upstream`` (a URL); yields the proxy's URL. With
    ``lateness``, the proxy writes there, when it stops, how late it wrote its chunks (``--lateness``: the run's
    own fidelity, :func:`network_sim.chunklog.read_lateness`)."""
    from network_sim.process import proxy
    from web3d.children import url

    host, _, port = upstream.removeprefix("http://").rpartition(":")
    args = ("--profile", profile, "--seed", str(seed), *(("--lateness", str(lateness)) if lateness else ()))
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


def with_path_frames(cfg: Any, flown: PathFile | None) -> Any:
    """``cfg`` with ``frames`` the count of its path file ``flown``; ``cfg`` itself without one."""
    return cfg if flown is None else replace(cfg, frames=len(flown.frames))


def path_options(cfg: PathRequests) -> list[str]:
    """A client's options for the path of ``cfg``: its path file, else the scripted path's frames and lap."""
    if cfg.path is not None:
        return ["--path", str(cfg.path)]
    return ["--frames", str(cfg.frames), "--orbit-frames", str(cfg.orbit_frames)]
