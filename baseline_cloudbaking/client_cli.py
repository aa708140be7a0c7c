"""`cloudbaking-client`: the cloud-baking client as its own process.

    cloudbaking-client --server http://127.0.0.1:8000 --scene lung_plane --frames 120 -k 10 --codec jpeg --gt-every 10 --out runs/cloud

Renders the DI of every frame locally, asks the server (through a network proxy, if one is in between)
for a GI map in a background thread when the newest map is k frames old or the view has left the
server's tolerance (one request in flight at most), decodes it, warps the newest map pixel by pixel to
each frame and composes. The server is checked at start (``GET /v1/health`` and ``/v1/scenes``): an
unreachable server, an unknown scene or an unserved resolution, codec or spp is one ``error:`` line.
Once running, a slow or dead server never stops the frames: failed requests are logged on stderr and
recorded, and the frames go on with the last map.

Writes under ``--out``: ``frames.csv`` (per frame: every stage in ms, the map's age and latency, what
the frame waited for, SSIM/PSNR against the path-traced GT every ``--gt-every`` frames, scored after the
run), ``requests.csv`` (per request: status, hit, bytes, every stage from transmission to blend; the
split is explained in :mod:`baseline_cloudbaking.client`) and ``summary.json``.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import typer

from baseline_cloudbaking.client import (
    CloudClientConfig,
    RemoteConfig,
    check_server,
    request_summary,
    run_client,
)
from baseline_cloudbaking.codecs import CODEC_NAMES
from gicore.blend import COMPOSITIONS
from gicore.cli import UserError, entry_point, require_between, writable_dir
from gicore.fileio import atomic_write_bytes, exclusive_run

app = typer.Typer(add_completion=False, help=__doc__)


@app.command()
def client_command(
    server: Annotated[
        str, typer.Option(help="base URL of cloudbaking-server (or of a network-sim proxy in front of it)")
    ],
    out: Annotated[Path, typer.Option(help="output folder")],
    scene: Annotated[
        str, typer.Option(help="built-in scene name or a .toml/.json spec (the server knows it by its file stem)")
    ] = "lung_plane",
    frames: Annotated[int, typer.Option(min=1, help="frames to run")] = 60,
    resolution: Annotated[
        int, typer.Option(min=8, max=2048, help="square resolution of every render and GI map")
    ] = 256,
    every: Annotated[
        int, typer.Option("--every", "-k", min=1, help="ask for a new GI map when the newest is k frames old")
    ] = 30,
    codec: Annotated[str, typer.Option(help=f"GI-map codec: {', '.join(CODEC_NAMES)}")] = "jpeg",
    gt_every: Annotated[
        int, typer.Option(min=0, help="compare with the path-traced GT every N frames, after the run (0: never)")
    ] = 0,
    gi_fov: Annotated[
        float | None, typer.Option(help="GI-camera FOV in degrees, in (0, 180) (default: the scene's, 90)")
    ] = None,
    local_fov: Annotated[
        float | None, typer.Option(help="local-camera FOV in degrees, in (0, 180) (default: the scene's, 60)")
    ] = None,
    orbit_frames: Annotated[
        int, typer.Option(min=1, help="frames per full orbit of the camera path (motion per frame)")
    ] = 300,
    tau: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="eq. 1 weight of DI in the blend (0: the GI map alone)")
    ] = 0.0,
    composition: Annotated[
        Literal[COMPOSITIONS], typer.Option(help="blend (eq. 1) or residual (current DI + warped indirect)")
    ] = "blend",  # type: ignore[valid-type]
    spp: Annotated[
        int,
        typer.Option(
            min=1, max=4096, help="samples per pixel of path tracing: the server's maps and the evaluation GT"
        ),
    ] = 64,
    denoise: Annotated[bool, typer.Option("--denoise/--no-denoise", help="OIDN-denoise the evaluation GT")] = True,
    connect_timeout: Annotated[float, typer.Option(min=0.001, help="seconds to wait for a TCP connection")] = 5.0,
    read_timeout: Annotated[
        float, typer.Option(min=0.001, help="seconds of silence that fail a request (bounds the server's render time)")
    ] = 30.0,
    deadline: Annotated[
        float, typer.Option(min=0.001, help="seconds after which a request fails however it is going")
    ] = 60.0,
    seed: Annotated[int, typer.Option(help="camera-path and render seed")] = 0,
) -> None:
    """Run the cloud-baking client against --server and print its summary."""
    for name, fov in (("--gi-fov", gi_fov), ("--local-fov", local_fov)):
        if fov is not None:
            require_between(name, fov, 0.0, 180.0)
    if codec not in CODEC_NAMES:
        raise UserError(f"--codec {codec!r} is unknown", f"choose one of {', '.join(CODEC_NAMES)}")
    from gicore.scene import load_scene

    spec = load_scene(scene)
    if gt_every:
        from gigan_local.client import check_denoiser

        check_denoiser(denoise)
    cfg = CloudClientConfig(
        scene=scene, frames=frames, resolution=resolution, every=every, gi_fov=gi_fov, local_fov=local_fov, orbit_frames=orbit_frames,
        tau=tau, composition=composition, codec=codec, spp=spp, denoise=denoise, gt_every=gt_every, seed=seed,
    )  # fmt: skip
    tolerance = check_server(server, cfg.server_name, resolution, codec, spp, connect_timeout + read_timeout)
    remote = RemoteConfig(
        server, cfg.server_name, resolution, codec, spp, di=composition == "residual", light_moves=spec.light.moves,
        connect_timeout_s=connect_timeout, read_timeout_s=read_timeout, deadline_s=deadline,
    )  # fmt: skip
    writable_dir(out)
    logging.basicConfig(format="%(asctime)s %(name)s: %(message)s", level=logging.INFO)
    with exclusive_run(out):
        rows, requests = run_client(cfg, remote, tolerance)
        summary = write_outputs(cfg, rows, requests, out)
    line = f"{frames} frames, {summary['fps']:.1f} fps; {summary['requests']} requests ({summary['hits']} hits, {summary['misses']} misses"
    failed = {s: n for s, n in summary["status"].items() if s != "ok"}
    line += "".join(f", {n} {s}" for s, n in failed.items()) + ")"
    if summary["median_total_ms"] is not None:
        line += f", median interaction latency {summary['median_total_ms']:.0f} ms"
    if "mean_ssim" in summary:
        line += f", mean SSIM {summary['mean_ssim']:.3f}, PSNR {summary['mean_psnr']:.2f} dB, LF error {summary['mean_lf_error']:.4f}"
    typer.echo(line)
    typer.echo(f"wrote {out / 'frames.csv'}, {out / 'requests.csv'} and {out / 'summary.json'}")


def write_outputs(cfg: CloudClientConfig, rows: list[dict], requests: list[dict], out: Path) -> dict:
    """``frames.csv``, ``requests.csv`` and ``summary.json`` under ``out``; returns the summary."""
    from gicore.loop import summarize, write_rows

    write_rows(rows, out / "frames.csv")
    write_rows(requests, out / "requests.csv")  # frame 0 always asks, so there is a record (if only "abandoned")
    summary = {"config": asdict(cfg)} | summarize(rows, cfg.every) | request_summary(requests)
    # maps come in the background, so the frame rate is what the frames took (not the amortised GI cost)
    summary["fps"] = 1000.0 / float(np.mean([float(r["frame_ms"]) for r in rows]))
    atomic_write_bytes(out / "summary.json", json.dumps(summary, indent=1).encode())
    return summary


main = entry_point(
    app, resume="the CSV files and summary.json are written when the run ends: run the same command again"
)

if __name__ == "__main__":
    main()
