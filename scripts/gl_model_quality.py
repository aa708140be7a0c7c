"""The shipped GIGAN model's quality on GL inputs at each level of detail, against Mitsuba's inputs (issue 22).

For GI cameras of each scene's held-out path (seed 0; the model trained on seed 2's), the model
(``gigan_local.inference.GIModel``, default ``model_fp16.onnx``) predicts the GI image from the inputs
``gigan_local.client.ModelSource`` gives it: DI + G-buffers at the GI camera, rendered by

- ``mitsuba_centre``: ``gicore.render.Renderer.render_di_gbuffers(centre=True)`` (1-spp DI), what the
  client renders with ``renderer = "mitsuba"``;
- ``mitsuba_jittered``: the same with G-buffers sampled at a random point of each pixel, as in the
  training data;
- ``gl_L<k>``: ``gicore.gl.GLRenderer`` at level of detail ``k`` (``gl_L0`` is full detail), and
  ``gl_auto`` at the level ``lod="auto"`` picks for the view.

Each prediction is scored (``gicore.loop.evaluate``: SSIM, PSNR, low-frequency error, tone-mapped) against
the path-traced GT at the same camera (``gicore.loop.render_gt``, OIDN-denoised). Rows per (scene, view,
input) with ``--csv``; the printed table is the mean per scene and input, and the mean paired SSIM
difference to ``mitsuba_centre`` with its standard error.

    .venv/bin/python scripts/gl_model_quality.py [SCENES...] [--views 6] [--spp 256] [--csv out.csv]

Not run by the tests (minutes: one path-traced GT per view).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gicore.gl import GLRenderer  # noqa: E402
from gicore.loop import evaluate, render_gt  # noqa: E402
from gicore.paths import camera_path, frame_seed, light_position  # noqa: E402
from gicore.render import Renderer  # noqa: E402
from gicore.scene import load_scene  # noqa: E402
from gigan_local.inference import DEFAULT_MODEL, GIModel  # noqa: E402

SCENES = ("lung_plane", "digestive_plane", "vessels_plane", "lung_cornell")
#: Frames between views: the light moves along its schedule from view to view.
FRAME_STEP = 37


def scene_rows(scene: str, model: GIModel, views: int, spp: int, seed: int, path_seed: int) -> list[dict[str, Any]]:
    spec = load_scene(scene)
    res = model.resolution
    mi = Renderer(spec, res)
    gl = GLRenderer(spec, res, lod="auto")
    levels = range(len(gl.lod_ratios))
    rows = []
    for i, cam in enumerate(camera_path(spec, views, seed=path_seed, resolution=res)):
        frame = i * FRAME_STEP
        light = light_position(spec, frame)
        t0 = time.perf_counter()
        gt = render_gt(mi, cam, light, spp, frame_seed(seed, "gt", frame), denoise=True)
        gt_s = time.perf_counter() - t0
        di_seed = frame_seed(seed, "gi_di", frame)
        inputs = {
            "mitsuba_centre": mi.render_di_gbuffers(cam, light, seed=di_seed, centre=True),
            "mitsuba_jittered": mi.render_di_gbuffers(cam, light, seed=di_seed),
        }
        picked = {}
        for level in levels:
            gl.lod = level
            inputs[f"gl_L{level}"] = gl.render_di_gbuffers(cam, light)
            picked[f"gl_L{level}"] = level
        gl.lod = "auto"
        inputs["gl_auto"] = gl.render_di_gbuffers(cam, light)
        picked["gl_auto"] = gl.last_level
        for name, buffers in inputs.items():
            level = picked.get(name, "")
            rows.append(
                {
                    "scene": scene,
                    "view": i,
                    "frame": frame,
                    "input": name,
                    "level": level,
                    "triangles": gl.level_triangles[level] if level != "" else gl.n_triangles,
                }
                | evaluate(model.predict(buffers), gt)
            )
        print(f"  {scene} view {i}: GT {gt_s:.1f} s, auto level {picked['gl_auto']}", file=sys.stderr)
    return rows


def summary(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Mean SSIM/PSNR/LF error per (scene, input) and the paired SSIM difference to ``mitsuba_centre``."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        mine = [r for r in rows if r["scene"] == scene]
        ref = {r["view"]: r["ssim"] for r in mine if r["input"] == "mitsuba_centre"}
        for name in dict.fromkeys(r["input"] for r in mine):
            sel = [r for r in mine if r["input"] == name]
            diff = np.array([r["ssim"] - ref[r["view"]] for r in sel])
            out.append(
                {
                    "scene": scene,
                    "input": name,
                    "views": len(sel),
                    "levels": " ".join(str(r["level"]) for r in sel),
                    "triangles": float(np.mean([r["triangles"] for r in sel])),
                    "ssim": float(np.mean([r["ssim"] for r in sel])),
                    "psnr": float(np.mean([r["psnr"] for r in sel])),
                    "lf_error": float(np.mean([r["lf_error"] for r in sel])),
                    "dssim_vs_mitsuba": float(diff.mean()),
                    "dssim_se": float(diff.std(ddof=1) / math.sqrt(len(diff))) if len(diff) > 1 else 0.0,
                }
            )
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scenes", nargs="*", default=list(SCENES), help="built-in scenes or spec files")
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL, help="exported ONNX model")
    parser.add_argument("--views", type=int, default=6, help="GI cameras per scene")
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel of the GT (OIDN-denoised)")
    parser.add_argument("--seed", type=int, default=0, help="render seed")
    parser.add_argument("--path-seed", type=int, default=0, help="camera path seed (the model trained on 2)")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime threads")
    parser.add_argument("--csv", type=Path, help="write the per-view rows to this CSV file")
    args = parser.parse_args(argv)
    model = GIModel(args.model, args.threads)
    rows = [r for s in args.scenes for r in scene_rows(s, model, args.views, args.spp, args.seed, args.path_seed)]
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    print(
        f"{'scene':16} {'input':17} {'triangles':>9} {'SSIM':>7} {'PSNR':>6} {'LF err':>7} {'dSSIM':>8}"
        f" {'+-':>7}  levels"
    )
    for r in summary(rows):
        print(
            f"{r['scene']:16} {r['input']:17} {r['triangles']:9.0f} {r['ssim']:7.4f} {r['psnr']:6.2f}"
            f" {r['lf_error']:7.4f}"
            f" {r['dssim_vs_mitsuba']:+8.4f} {r['dssim_se']:7.4f}  {r['levels'] if r['input'] == 'gl_auto' else ''}"
        )


if __name__ == "__main__":
    main()
