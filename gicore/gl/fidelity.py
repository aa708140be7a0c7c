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

This module imports ``gicore.render`` (Mitsuba) only inside its functions; the renderer modules of
``gicore.gl`` never do.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from gicore.camera import Camera
from gicore.metrics import ssim
from gicore.paths import camera_path, light_position
from gicore.scene import load_scene
from gicore.timing import summarize_ms
from gicore.tonemap import tonemap

#: The G-buffer channels compared (the mask is compared through the silhouette count).
CHANNELS = ("albedo", "normal", "depth", "position")
#: A depth step between neighbours larger than this fraction of the depth is a discontinuity, beyond what
#: any surface's slope gives between pixel centres (a grazing plane at the scenes' cameras: < 2 %).
DEPTH_JUMP = 0.05


def _dilate(edge: np.ndarray) -> np.ndarray:
    """Pixels with an ``edge`` pixel in their 3x3 neighbourhood."""
    padded = np.pad(edge, 1)
    h, w = edge.shape
    return np.any([padded[i : i + h, j : j + w] for i in range(3) for j in range(3)], axis=0)


def _changes(x: np.ndarray, differ: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """HxW: where ``x`` (HxW...) differs from its right or lower neighbour (both pixels marked)."""
    edge = np.zeros(x.shape[:2], dtype=bool)
    dx, dy = differ(x[:, 1:], x[:, :-1]), differ(x[1:], x[:-1])
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:] |= dy
    edge[:-1] |= dy
    return edge


def silhouettes(*gbuffers: dict[str, np.ndarray], depth_jump: float = DEPTH_JUMP) -> np.ndarray:
    """HxW bool: pixels near a change of surface (mask), object (albedo) or a depth discontinuity in any of
    the given G-buffer sets, or whose masks disagree between them."""
    edge = np.zeros(gbuffers[0]["mask"].shape[:2], dtype=bool)
    for gb in gbuffers:
        edge |= _changes(gb["mask"][..., 0] > 0.5, np.not_equal)
        edge |= _changes(gb["albedo"], lambda a, b: np.any(np.abs(a - b) > 1e-6, axis=-1))
        d = gb["depth"][..., 0]
        edge |= _changes(d, lambda a, b: np.abs(a - b) > depth_jump * np.maximum(np.minimum(a, b), 1e-9))
    masks = [gb["mask"][..., 0] > 0.5 for gb in gbuffers]
    for m in masks[1:]:
        edge |= m != masks[0]
    return _dilate(edge)


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
    from gicore.gl.renderer import GLRenderer
    from gicore.loop import texel_depth
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
    parser.add_argument("scene", nargs="?", default="lung_plane", help="built-in scene or spec file")
    parser.add_argument("--resolution", type=int, default=256, help="fidelity resolution (square)")
    parser.add_argument("--timing", type=int, nargs="*", default=[256, 512], help="timing resolutions")
    parser.add_argument("--repeats", type=int, default=7, help="timed repeats per pass (after 2 warm-ups)")
    parser.add_argument("--reference-spp", type=int, default=64, help="samples of the converged Mitsuba DI")
    parser.add_argument("--view", type=int, default=0, help="which of 8 path cameras to compare at")
    args = parser.parse_args(argv)
    from gicore.gl.context import gl_info

    spec = load_scene(args.scene)
    print("GL:", ", ".join(f"{k}={v}" for k, v in gl_info().items()))
    camera = camera_path(spec, 8, resolution=args.resolution)[args.view]
    result = compare(spec, args.resolution, camera, light_position(spec, 0), args.reference_spp)
    _print_fidelity(spec.name, args.resolution, result)
    rows = [row for res in args.timing for row in timings(spec, res, args.repeats)]
    _print_timings(rows)


if __name__ == "__main__":
    main()
