"""`gigan-client`: run the GIGAN client loop along a scene's camera path (its own process).

    gigan-client --scene lung_plane --frames 120 -k 30 --warp structure --gi-source gt --gt-every 10 --out runs/client

The path is the scene's fly-through, or a recorded session with ``--path FILE`` (:mod:`gicore.path_file`).
Writes under ``--out``: ``path.json`` (the path flown, a path file that ``--path`` replays), ``frames.csv``
(per-frame stage times in ms, valid fraction, SSIM/PSNR where GT was rendered) and ``summary.json`` (amortised
fps, median stage times, mean quality, the renderer that ran the raster passes: ``--renderer gl`` falls back
to mitsuba with one warning where no GL context opens); optionally PNG frames and an MP4 (needs
imageio-ffmpeg). Its options are derived from :class:`gigan_local.client.ClientConfig` (the fields both
clients share live in :class:`gicore.run_config.PathRunConfig`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from gicore import option_groups
from gicore.error_policy import entry_point
from gicore.fileio import exclusive_run
from gicore.options import build_config, config_command, extra
from gigan_local.client import ClientConfig, run

app = typer.Typer(add_completion=False, help=__doc__)


def client_command(given: dict[str, Any], *, with_gt: bool, out: Path, save_frames: bool, video: bool) -> None:
    """Run the client and print its summary."""
    if with_gt:
        given = given | {"gt_every": 1}
    cfg = build_config(ClientConfig, given)
    cfg.check_gt_cache()
    with exclusive_run(out):
        summary = run(cfg, out, save_frames=save_frames, video=video)
    line = f"{summary['frames']} frames, {summary['fps']:.1f} fps"
    line += f" (local {summary['local_ms']:.1f} ms + GI {summary['gi_ms']:.0f} ms / {cfg.every})"
    if "mean_ssim" in summary:
        line += f", mean SSIM {summary['mean_ssim']:.3f}, PSNR {summary['mean_psnr']:.2f} dB"
        line += f", LF error {summary['mean_lf_error']:.4f}"
    typer.echo(line)
    typer.echo(f"wrote {out / 'path.json'}, {out / 'frames.csv'} and {out / 'summary.json'}")


config_command(
    app,
    ClientConfig,
    client_command,
    extras=[
        extra(
            "with_gt",
            Annotated[bool, typer.Option("--with-gt", help="compare with the GT every frame (= --gt-every 1)")],
            False,
        ),
        option_groups.out("path.json, frames.csv, summary.json and the frames asked for", Path("runs/client")),
        extra(
            "save_frames",
            Annotated[bool, typer.Option("--save-frames", help="write the composed frames as PNG")],
            False,
        ),
        extra(
            "video", Annotated[bool, typer.Option("--video", help="also write an MP4 (needs imageio-ffmpeg)")], False
        ),
    ],
)

main = entry_point(app, resume="frames.csv and summary.json are written when the run ends: run the same command again")

if __name__ == "__main__":
    main()
