"""How closely the GL passes reproduce Mitsuba's, and what each costs: ``python -m gicore.gl.fidelity``.

G-buffers: per channel, mean and max |gl - mitsuba| on the same camera, away from silhouettes and on them
(:func:`silhouettes`: pixels whose 3x3 neighbourhood, in either render, changes surface, object or depth
discontinuously; there a pixel centre and a ray through another point of the pixel can hit different
surfaces). Against Mitsuba's centre-sampled pass (``centre=True``, what a rasteriser samples) and its
default one (one sample at a random point of each pixel, what the data sets hold).

DI: SSIM (``gicore.metrics``, tone-mapped) of GL against Mitsuba's 1-spp DI (the pass GL replaces) and
against its converged DI (``reference_spp``, the pixel's average), plus the mean absolute error.

Timing: median ms per pass (after warm-up) of GL and of the Mitsuba pass it replaces, called alternately
(both see the same load), cameras alternating along the scene's path as in ``bench render``.

Level of detail (``--lod``, :func:`lod_table`): per level of ``gicore.gl.lod`` and for ``lod="auto"``, the
GI-camera pass's triangles, its median ms against Mitsuba's pass (alternating, as above), its G-buffer
error against full detail and against Mitsuba's centre-sampled pass, and DI SSIM against Mitsuba; rows a
bench can write as CSV (``--csv``). ``bench quality --renderers gl,mitsuba --gl-lod LOD`` adds the shipped
model's SSIM and LF error on such inputs.

This module imports ``gicore.render`` (Mitsuba) only inside its functions; the renderer modules of
``gicore.gl`` never do.
"""

from __future__ import annotations

import argparse
import csv
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gicore.camera import Camera
from gicore.gl.edges import DEPTH_JUMP, silhouettes
from gicore.metrics import ssim
from gicore.paths import camera_path, light_position
from gicore.scene import load_scene
from gicore.timing import summarize_ms
from gicore.tonemap import tonemap

#: The G-buffer channels compared (the mask is compared through the silhouette count).
CHANNELS = ("albedo", "normal", "depth", "position")
__all__ = ["CHANNELS", "DEPTH_JUMP", "compare", "di_errors", "gbuffer_errors", "lod_table", "silhouettes", "timings"]


def gbuffer_errors(gl: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Rows (channel, region, pixels, mean_abs, max_abs) of |gl - ref| per channel, interior and silhouette."""
    sil = silhouettes(gl, ref)
    rows = []
    for name in CHANNELS:
        err = np.abs(gl[name].astype(np.float64) - ref[name]).max(axis=-1)
        for region, where in (("interior", ~sil), ("silhouette", sil)):
            e = err[where]
            rows.append(
                {
                    "channel": name,
                    "region": region,
                    "pixels": int(where.sum()),
                    "mean_abs": float(e.mean()) if e.size else 0.0,
                    "max_abs": float(e.max()) if e.size else 0.0,
                }
            )
    return rows


def di_errors(gl: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> dict[str, float]:
    """SSIM of the tone-mapped images and mean |gl - ref| (linear; over ``mask`` where given)."""
    err = np.abs(gl.astype(np.float64) - ref)
    where = np.ones(gl.shape[:2], bool) if mask is None else mask
    return {"ssim": ssim(tonemap(gl), tonemap(ref)), "mean_abs": float(err[where].mean())}


def compare(spec, resolution: int, camera: Camera, light=None, reference_spp: int = 64, seed: int = 0) -> dict:
    """Every comparison of the module docstring for one view: {"gbuffers": {reference: rows}, "di": ...}."""
    from gicore.gl.renderer import GLRenderer
    from gicore.render import Renderer

    gl, mi = GLRenderer(spec, resolution), Renderer(spec, resolution)
    out = gl.render_di_gbuffers(camera, light)
    refs = {
        "mitsuba_centre": mi.render_gbuffers(camera, seed, centre=True),
        "mitsuba_jittered": mi.render_gbuffers(camera, seed),
    }
    interior = ~silhouettes(out, refs["mitsuba_centre"])
    di_refs = {
        "mitsuba_1spp": mi.render_di(camera, light, spp=1, seed=seed),
        f"mitsuba_{reference_spp}spp": mi.render_di(camera, light, spp=reference_spp, seed=seed),
    }
    return {
        "gbuffers": {name: gbuffer_errors(out, ref) for name, ref in refs.items()},
        "di": {
            name: di_errors(out["di"], ref) | {"mean_abs_interior": di_errors(out["di"], ref, interior)["mean_abs"]}
            for name, ref in di_refs.items()
        },
        "triangles": gl.n_triangles,
    }


def timings(spec, resolution: int, repeats: int = 7, warmup: int = 2, seed: int = 0) -> list[dict[str, Any]]:
    """Median and p95 ms of each GL pass and of the Mitsuba pass it replaces (see the module docstring)."""
    from gicore.gi_map import texel_depth
    from gicore.gl.renderer import GLRenderer
    from gicore.render import Renderer

    gl, mi = GLRenderer(spec, resolution), Renderer(spec, resolution)
    cams = camera_path(spec, 8, seed=seed, resolution=resolution)
    light = light_position(spec, 0)
    moving = [light_position(spec, f) for f in range(1, 50)]
    state = {"cam": 0, "light": 0}

    def cam() -> Camera:
        state["cam"] += 1
        return cams[state["cam"] % len(cams)]

    def next_light():
        state["light"] += 1
        return moving[state["light"] % len(moving)]

    passes: dict[str, tuple[Callable[[], Any], Callable[[], Any]]] = {
        "di": (lambda: gl.render_di(cam(), light), lambda: mi.render_di(cam(), light)),
        "di_moving_light": (lambda: gl.render_di(cam(), next_light()), lambda: mi.render_di(cam(), next_light())),
        "gbuffers": (lambda: gl.render_gbuffers(cam()), lambda: mi.render_gbuffers(cam(), centre=True)),
        "di_gbuffers": (
            lambda: gl.render_di_gbuffers(cam(), light),
            lambda: mi.render_di_gbuffers(cam(), light, centre=True),
        ),
        "uv": (lambda: gl.render_uv(cam()), lambda: mi.render_uv(cam())),
        "depth": (lambda: gl.render_depth(cam()), lambda: texel_depth(mi, cam())),
    }
    rows = []
    for fns in passes.values():  # every pass once first: compilation and first-use costs stay out of all
        for fn in fns:
            fn()
    for name, fns in passes.items():
        # GL and Mitsuba alternate call by call, so that both see the same load on a shared machine
        samples: dict[str, list[float]] = {"gl": [], "mitsuba": []}
        for i in range(warmup + repeats):
            for system, fn in zip(samples, fns):
                t0 = time.perf_counter()
                fn()
                if i >= warmup:
                    samples[system].append(time.perf_counter() - t0)
        for system, times in samples.items():
            rows.append({"pass": name, "system": system, "resolution": resolution} | summarize_ms(times))
    updates = gl.shadow_updates
    rows.append({"pass": "shadow_map_renders", "system": "gl", "resolution": resolution, "median": float(updates)})
    return rows


def _alternate(fns: tuple[Callable[[], Any], Callable[[], Any]], repeats: int, warmup: int) -> list[list[float]]:
    """Seconds of each of two calls, called alternately ``warmup + repeats`` times (warm-ups dropped)."""
    samples: list[list[float]] = [[], []]
    for i in range(warmup + repeats):
        for times, fn in zip(samples, fns):
            t0 = time.perf_counter()
            fn()
            if i >= warmup:
                times.append(time.perf_counter() - t0)
    return samples


def lod_table(
    spec,
    resolution: int = 256,
    views: int = 8,
    repeats: int = 15,
    warmup: int = 2,
    reference_spp: int = 64,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """One row per level of detail of the GL renderer (``gicore.gl.lod``), and one for ``lod="auto"``: the GI-
    camera pass (DI + G-buffers, static light) on ``views`` GI cameras of the scene's path.

    Columns: ``scene``, ``resolution``, ``lod`` (a level or "auto"), ``ratio_kept`` (fraction of the large
    meshes' triangles), ``triangles`` (mean over the views; "auto" picks per view), ``levels`` (the levels
    drawn, per view), ``gl_ms`` and ``mitsuba_ms`` (median, after ``warmup``, GL and Mitsuba's centre-sampled
    ``render_di_gbuffers`` called alternately on the same cameras), ``gl_over_mitsuba``; the G-buffer error of
    the level against full detail (``lod_normal``, ``lod_depth``, ``lod_coverage``: mean over the views of
    :func:`gicore.gl.lod.lod_errors`, and ``*_max`` their largest), ``auto_bound_ok`` (every view within the
    renderer's ``lod_bound``); the interior mean |gl - mitsuba| per channel against Mitsuba's centre-sampled
    pass (``mitsuba_<channel>``, as :func:`gbuffer_errors`); DI SSIM against Mitsuba's 1-spp DI (the pass GL
    replaces) and its ``reference_spp`` DI (``di_ssim_1spp``, ``di_ssim_ref``); and ``shadow_lod``.
    """
    from gicore.gl.lod import LOD_CHANNELS, lod_errors, within
    from gicore.gl.renderer import GLRenderer
    from gicore.render import Renderer

    gl, mi = GLRenderer(spec, resolution, lod="auto"), Renderer(spec, resolution)
    cams = camera_path(spec, views, seed=seed, resolution=resolution)
    light = light_position(spec, 0)
    gl.lod = 0
    full = [gl.render_di_gbuffers(c, light) for c in cams]
    centre = [mi.render_gbuffers(c, seed, centre=True) for c in cams]
    di_one = [mi.render_di(c, light, spp=1, seed=seed) for c in cams]
    di_ref = [mi.render_di(c, light, spp=reference_spp, seed=seed) for c in cams]
    rows = []
    for lod in [*range(len(gl.lod_ratios)), "auto"]:
        gl.lod = lod
        outs, levels = [], []
        for c in cams:
            outs.append(gl.render_di_gbuffers(c, light))
            levels.append(gl.last_level)
        lod_err = [lod_errors(o, f) for o, f in zip(outs, full)]
        mi_err = [
            {r["channel"]: r["mean_abs"] for r in gbuffer_errors(o, ref) if r["region"] == "interior"}
            for o, ref in zip(outs, centre)
        ]
        state = {"i": 0}

        def cam() -> Camera:
            state["i"] += 1
            return cams[state["i"] % len(cams)]

        times = _alternate(
            (lambda: gl.render_di_gbuffers(cam(), light), lambda: mi.render_di_gbuffers(cam(), light, centre=True)),
            repeats,
            warmup,
        )
        gl_ms, mi_ms = (summarize_ms(t)["median"] for t in times)
        row = {
            "scene": spec.name,
            "resolution": resolution,
            "lod": lod,
            "ratio_kept": gl.lod_ratios[lod] if lod != "auto" else float("nan"),
            "triangles": float(np.mean([gl.level_triangles[k] for k in levels])),
            "levels": " ".join(map(str, levels)),
            "gl_ms": gl_ms,
            "mitsuba_ms": mi_ms,
            "gl_over_mitsuba": gl_ms / mi_ms,
        }
        for c in LOD_CHANNELS:
            row[f"lod_{c}"] = float(np.mean([e[c] for e in lod_err]))
            row[f"lod_{c}_max"] = float(np.max([e[c] for e in lod_err]))
        row["auto_bound_ok"] = all(within(e, gl.lod_bound) for e in lod_err)
        for c in CHANNELS:
            row[f"mitsuba_{c}"] = float(np.mean([e[c] for e in mi_err]))
        row["di_ssim_1spp"] = float(np.mean([ssim(tonemap(o["di"]), tonemap(r)) for o, r in zip(outs, di_one)]))
        row["di_ssim_ref"] = float(np.mean([ssim(tonemap(o["di"]), tonemap(r)) for o, r in zip(outs, di_ref)]))
        row["shadow_lod"] = gl.shadow_lod
        rows.append(row)
    return rows


def _print_lod_table(rows: list[dict[str, Any]]) -> None:
    print(f"\n{rows[0]['scene']} at {rows[0]['resolution']}²: GI-camera pass (DI + G-buffers) per level of detail")
    head = (
        f"{'lod':>4} {'triangles':>9} {'gl ms':>6} {'mi ms':>6} {'gl/mi':>5}  {'normal':>8} {'depth':>8} {'cover':>8}"
    )
    print(head + f"  {'vs mi: n':>8} {'depth':>8}  {'DI SSIM 1spp':>12} {'ref':>6}  levels")
    for r in rows:
        print(
            f"{r['lod']!s:>4} {r['triangles']:9.0f} {r['gl_ms']:6.2f} {r['mitsuba_ms']:6.2f}"
            f" {r['gl_over_mitsuba']:5.2f}"
            f"  {r['lod_normal']:8.2e} {r['lod_depth']:8.2e} {r['lod_coverage']:8.2e}"
            f"  {r['mitsuba_normal']:8.2e} {r['mitsuba_depth']:8.2e}  {r['di_ssim_1spp']:12.4f} {r['di_ssim_ref']:6.4f}"
            f"  {r['levels'] if r['lod'] == 'auto' else ''}"
        )


def _print_fidelity(scene: str, resolution: int, result: dict) -> None:
    print(f"\n{scene} at {resolution}², {result['triangles']:,} triangles: |gl - mitsuba| per G-buffer channel")
    print(f"{'reference':18} {'channel':9} {'region':10} {'pixels':>7} {'mean abs':>10} {'max abs':>10}")
    for ref, rows in result["gbuffers"].items():
        for r in rows:
            cells = f"{r['pixels']:7d} {r['mean_abs']:10.2e} {r['max_abs']:10.2e}"
            print(f"{ref:18} {r['channel']:9} {r['region']:10} {cells}")
    print(f"\n{'DI vs':18} {'SSIM':>7} {'mean abs':>10} {'interior':>10}")
    for ref, d in result["di"].items():
        print(f"{ref:18} {d['ssim']:7.4f} {d['mean_abs']:10.2e} {d['mean_abs_interior']:10.2e}")


def _print_timings(rows: list[dict[str, Any]]) -> None:
    print(f"\n{'pass':18} {'res':>5} {'gl ms':>9} {'mitsuba ms':>11} {'speed-up':>9}")
    table: dict[tuple[str, int], dict[str, float]] = {}
    for r in rows:
        table.setdefault((r["pass"], r["resolution"]), {})[r["system"]] = r["median"]
    for (name, res), t in table.items():
        if "mitsuba" in t:
            print(f"{name:18} {res:5d} {t['gl']:9.2f} {t['mitsuba']:11.2f} {t['mitsuba'] / t['gl']:8.1f}x")
        else:
            print(f"{name:18} {res:5d} {t['gl']:9.0f}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m gicore.gl.fidelity", description=__doc__.split("\n")[0])
    parser.add_argument("scenes", nargs="*", default=["lung_plane"], help="built-in scenes or spec files")
    parser.add_argument("--resolution", type=int, default=256, help="fidelity resolution (square)")
    parser.add_argument("--timing", type=int, nargs="*", default=[256, 512], help="timing resolutions")
    parser.add_argument("--repeats", type=int, default=7, help="timed repeats per pass (after 2 warm-ups)")
    parser.add_argument("--reference-spp", type=int, default=64, help="samples of the converged Mitsuba DI")
    parser.add_argument("--view", type=int, default=0, help="which of 8 path cameras to compare at")
    parser.add_argument("--lod", action="store_true", help="only the level-of-detail table (lod_table)")
    parser.add_argument("--csv", type=Path, help="with --lod: also write the table's rows to this CSV file")
    args = parser.parse_args(argv)
    from gicore.gl.context import gl_info

    print("GL:", ", ".join(f"{k}={v}" for k, v in gl_info().items()))
    table: list[dict[str, Any]] = []
    for scene in args.scenes:
        spec = load_scene(scene)
        if args.lod:
            rows = lod_table(spec, args.resolution, reference_spp=args.reference_spp, repeats=2 * args.repeats + 1)
            _print_lod_table(rows)
            table += rows
            continue
        camera = camera_path(spec, 8, resolution=args.resolution)[args.view]
        result = compare(spec, args.resolution, camera, light_position(spec, 0), args.reference_spp)
        _print_fidelity(spec.name, args.resolution, result)
        _print_timings([row for res in args.timing for row in timings(spec, res, args.repeats)])
    if args.csv and table:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(table[0]))
            writer.writeheader()
            writer.writerows(table)


if __name__ == "__main__":
    main()
