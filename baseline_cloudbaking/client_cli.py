"""`cloudbaking-client`: the cloud-baking client as its own process.

    cloudbaking-client --server http://127.0.0.1:8000 --scene lung_plane --frames 120 -k 10 --out runs/cloud

Renders the DI of every frame locally, asks the server (through a network proxy, if one is in between)
for a GI map in background threads when no map it holds or has asked for serves the view by the server's
tolerance (``--hold tolerance``; ``--hold none``: when the newest map is k frames old or the view has left
the tolerance), or, with ``--prefetch extrapolate``, the view its motion will reach when the answer comes
(``--in-flight`` requests at most, one by default), decodes it, warps the held map that serves the view best
pixel by pixel to each frame and composes; ``--frame-rate`` paces the frames as a display would.
The server is checked at start (``GET /v1/health`` and ``/v1/scenes``): an unreachable server, an unknown
scene or an unserved resolution, codec or spp is one ``error:`` line. Once running, a slow or dead server
never stops the frames: failed requests are logged on stderr and recorded, and the frames go on with the
last map.

Flies the scene's fly-through, or a recorded session (``--path FILE``, :mod:`gicore.path_file`). Writes
under ``--out``: ``path.json`` (the path flown, which ``--path`` replays), ``frames.csv`` (per frame: every
stage in ms, the map's age and latency, what it waited for, SSIM/PSNR against the path-traced GT every
``--gt-every`` frames, scored after the run, and how long its view waited for a map within tolerance:
``perceived_ms``, :func:`baseline_cloudbaking.client_run.perceived_latency`), ``requests.csv`` (per request:
status, hit, bytes, every stage from transmission to blend, split as :mod:`baseline_cloudbaking.client`
says) and ``summary.json`` (``renderer``: the one that ran the local DI and the warp's mask pass; gl without
a context falls back to mitsuba with one warning). Options: the fields of
:class:`~baseline_cloudbaking.client_run.CloudClientConfig` and :class:`~gicore.run_config.PathRunConfig`.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from baseline_cloudbaking.client_run import CloudClientConfig, check_server, request_summary, run_client
from gicore import option_groups
from gicore.error_policy import entry_point, writable_dir
from gicore.fileio import atomic_write_bytes, exclusive_run
from gicore.mitsuba_variant import check_denoiser
from gicore.options import build_config, config_command, extra

app = typer.Typer(add_completion=False, help=__doc__)


def client_command(given: dict[str, Any], *, server: str, out: Path) -> None:
    """Run the cloud-baking client against --server and print its summary."""
    from gicore.path_file import flown_path, write_path_file
    from gicore.scene import load_scene

    cfg = build_config(CloudClientConfig, given)
    spec = load_scene(cfg.scene)  # a bad spec or path file is one error line before the server is asked
    flown = flown_path(spec, cfg, cfg.seed, cfg.local_fov_of(spec))
    cfg.check_gt_cache()
    if cfg.gt_every:
        check_denoiser(cfg.denoise)
    timeout = cfg.connect_timeout + cfg.read_timeout
    tolerance = check_server(server, cfg.server_name, cfg.resolution, cfg.codec, cfg.spp, timeout)
    writable_dir(out)
    logging.basicConfig(format="%(asctime)s %(name)s: %(message)s", level=logging.INFO)
    with exclusive_run(out):
        write_path_file(out / "path.json", flown.scene, flown.frames, flown.source)
        rows, requests, used = run_client(cfg, server, tolerance, flown)
        summary = write_outputs(cfg, rows, requests, out, renderer=used)
    line = f"{summary['frames']} frames, {summary['fps']:.1f} fps; {summary['requests']} requests"
    line += f" ({summary['hits']} hits, {summary['misses']} misses"
    failed = {s: n for s, n in summary["status"].items() if s != "ok"}
    line += "".join(f", {n} {s}" for s, n in failed.items()) + ")"
    if summary["median_total_ms"] is not None:
        line += f", median interaction latency {summary['median_total_ms']:.0f} ms"
    line += f"; {summary['in_tolerance']:.0%} of frames within tolerance"
    if "perceived_ms" in summary["median"]:
        line += f", median perceived latency {summary['median']['perceived_ms']:.0f} ms"
    if "mean_ssim" in summary:
        line += f", mean SSIM {summary['mean_ssim']:.3f}, PSNR {summary['mean_psnr']:.2f} dB"
        line += f", LF error {summary['mean_lf_error']:.4f}"
    typer.echo(line)
    typer.echo(f"wrote {out / 'path.json'}, {out / 'frames.csv'}, {out / 'requests.csv'} and {out / 'summary.json'}")


SERVER_HELP = "base URL of cloudbaking-server (or of a network-sim proxy in front of it)"
config_command(
    app,
    CloudClientConfig,
    client_command,
    extras=[
        extra("server", Annotated[str, typer.Option("--server", help=SERVER_HELP)]),
        option_groups.out("path.json, frames.csv, requests.csv and summary.json"),
    ],
)


def write_outputs(
    cfg: CloudClientConfig, rows: list[dict], requests: list[dict], out: Path, renderer: str | None = None
) -> dict:
    """``frames.csv``, ``requests.csv`` and ``summary.json`` under ``out``; returns the summary. ``renderer``:
    the renderer that ran the raster passes (default: the one the config asks for); the summary's
    ``warp_backend`` is the backend that ran the warp and the composition on it."""
    from gicore.frame_rows import summarize, write_rows

    write_rows(rows, out / "frames.csv")
    write_rows(requests, out / "requests.csv")  # frame 0 always asks, so there is a record (if only "abandoned")
    from gicore.gl.frame import warp_backend

    summary = {"config": cfg.as_json(), "frames": len(rows), "renderer": renderer or cfg.renderer}
    summary["warp_backend"] = warp_backend(cfg.warp_backend, summary["renderer"])
    summary |= summarize(rows, cfg.every) | request_summary(requests)
    # maps come in the background, so the frame rate is what the frames took (not the amortised GI cost)
    summary["fps"] = 1000.0 / float(np.mean([float(r["frame_ms"]) for r in rows]))
    summary["in_tolerance"] = float(np.mean([int(r["in_tolerance"]) for r in rows]))
    atomic_write_bytes(out / "summary.json", json.dumps(summary, indent=1).encode())
    return summary


main = entry_point(
    app, resume="the CSV files and summary.json are written when the run ends: run the same command again"
)

if __name__ == "__main__":
    main()
