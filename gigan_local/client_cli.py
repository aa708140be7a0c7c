"""`gigan-client`: run the GIGAN client loop along a scene's camera path (its own process).

    gigan-client --scene lung_plane --frames 120 -k 30 --warp structure --gi-source gt --gt-every 10 --out runs/client

Writes ``frames.csv`` (per-frame stage times in ms, valid fraction, SSIM/PSNR where GT was rendered) and
``summary.json`` (amortised fps, median stage times, mean quality) under ``--out``; optionally PNG frames
and an MP4 (needs imageio-ffmpeg).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer

from gicore.blend import COMPOSITIONS
from gicore.cli import UserError, entry_point, require_between
from gicore.fileio import exclusive_run
from gigan_local.client import GI_SOURCES, WARPS, ClientConfig, run

app = typer.Typer(add_completion=False, help=__doc__)


@app.command()
def client_command(
    scene: Annotated[str, typer.Option(help="built-in scene name or a .toml/.json scene spec")] = "lung_plane",
    frames: Annotated[int, typer.Option(min=1, help="frames to run")] = 60,
    resolution: Annotated[int, typer.Option(min=8, max=2048, help="square resolution of every render")] = 256,
    every: Annotated[int, typer.Option("--every", "-k", min=1, help="a new GI map every k frames")] = 30,
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
        float,
        typer.Option(
            min=0.0,
            max=1.0,
            help="eq. 1 weight of DI in the blend (0: the GI map alone, which already holds direct light)",
        ),
    ] = 0.0,
    composition: Annotated[
        Literal[COMPOSITIONS], typer.Option(help="blend (eq. 1) or residual (current DI + warped indirect)")
    ] = "blend",  # type: ignore[valid-type]
    warp: Annotated[
        Literal[WARPS], typer.Option(help="structure (Alg. 1) or none (the map pasted as is, made at the local FOV)")
    ] = "structure",  # type: ignore[valid-type]
    gi_source: Annotated[
        Literal[GI_SOURCES], typer.Option(help="model (ONNX generator) or gt (path-traced GT stand-in)")
    ] = "gt",  # type: ignore[valid-type]
    model: Annotated[
        Path | None,
        typer.Option(help="ONNX model (default: the shipped gigan_local/models/gigan_default/model_fp16.onnx)"),
    ] = None,
    spp: Annotated[int, typer.Option(min=1, help="samples per pixel of path-traced GT renders")] = 64,
    denoise: Annotated[bool, typer.Option("--denoise/--no-denoise", help="OIDN-denoise the GT renders")] = True,
    gt_every: Annotated[int, typer.Option(min=0, help="compare with the GT every N frames (0: never)")] = 0,
    with_gt: Annotated[
        bool, typer.Option("--with-gt", help="compare with the GT every frame (= --gt-every 1)")
    ] = False,
    threads: Annotated[int, typer.Option(min=1, help="onnxruntime threads")] = 2,
    seed: Annotated[int, typer.Option(help="camera-path and render seed")] = 0,
    out: Annotated[Path, typer.Option(help="output folder")] = Path("runs/client"),
    save_frames: Annotated[bool, typer.Option("--save-frames", help="write the composed frames as PNG")] = False,
    video: Annotated[bool, typer.Option("--video", help="also write an MP4 (needs imageio-ffmpeg)")] = False,
) -> None:
    """Run the client and print its summary."""
    for name, fov in (("--gi-fov", gi_fov), ("--local-fov", local_fov)):
        if fov is not None:  # only an absent option means "the scene's FOV"
            require_between(name, fov, 0.0, 180.0)
    if model is not None and not model.is_file():
        raise UserError(
            f"--model {model} is not a file",
            "give an ONNX file written by gigan-export, or leave --model out for the shipped model",
        )
    try:
        cfg = ClientConfig(
            scene=scene,
            frames=frames,
            resolution=resolution,
            every=every,
            gi_fov=gi_fov,
            local_fov=local_fov,
            orbit_frames=orbit_frames,
            tau=tau,
            composition=composition,
            warp=warp,
            gi_source=gi_source,
            model=model,
            spp=spp,
            denoise=denoise,
            gt_every=1 if with_gt else gt_every,
            seed=seed,
            threads=threads,
        )
    except ValueError as err:  # a combination of options the client refuses
        raise UserError(f"invalid client options: {err}", "see 'gigan-client --help'") from None
    with exclusive_run(out):
        summary = run(cfg, out, save_frames=save_frames, video=video)
    line = f"{cfg.frames} frames, {summary['fps']:.1f} fps (local {summary['local_ms']:.1f} ms + GI {summary['gi_ms']:.0f} ms / {cfg.every})"
    if "mean_ssim" in summary:
        line += f", mean SSIM {summary['mean_ssim']:.3f}, PSNR {summary['mean_psnr']:.2f} dB, LF error {summary['mean_lf_error']:.4f}"
    typer.echo(line)
    typer.echo(f"wrote {out / 'frames.csv'} and {out / 'summary.json'}")


main = entry_point(app, resume="frames.csv and summary.json are written when the run ends: run the same command again")

if __name__ == "__main__":
    main()
