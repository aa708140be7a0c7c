"""`bench pareto`: error against run time over every speed/quality knob of both systems, per GI map and per
frame, with the fronts (docs/architecture.md, bench pareto). The knobs: :mod:`bench.pareto_knobs`; the fronts
and the best configuration per time budget (``pareto.md``): :mod:`bench.pareto_fronts`."""

from __future__ import annotations

from functools import partial

from bench.pareto_fronts import PARTS
from bench.pareto_knobs import (
    Context,
    ParetoConfig,
    Points,
    bake_resolution,
    bake_spp,
    codecs_and_links,
    gigan_maps,
    mark_dominated,
    per_frame,
    tolerances,
)
from bench.runner import Bench, Block, Section
from gicore.results import Results


def measure(cfg: ParetoConfig, res: Results, frequency: Bench) -> None:
    from gicore.paths import camera_path, light_position
    from gicore.render import Renderer
    from gicore.scene import load_scene

    spec = load_scene(cfg.scenes[0])
    frames = [int(i * 300 / cfg.views) for i in range(cfg.views)]
    path = camera_path(spec, 300, seed=res.seed, fov=spec.camera.local_fov, resolution=cfg.resolution)
    ctx = Context(
        cfg,
        spec,
        Renderer(spec, cfg.resolution),
        [path[f] for f in frames],
        [light_position(spec, f) for f in frames],
        res.seed,
    )
    pts = Points()
    gigan_maps(ctx, pts)
    bake_spp(ctx, pts, cfg.from_dir)
    bake = bake_resolution(ctx, pts)
    hit_path = codecs_and_links(ctx, pts, bake["bake_ms"])
    tolerances(ctx, pts, bake["bake_ms"], hit_path)
    per_frame(ctx, pts, res, frequency)
    mark_dominated(pts.items)
    for p in pts.items:
        add = {"system": p["system"], "scene": spec.name, **p["config"]}
        res.add(**add, metric="run_time", value=p["time"], unit="ms", stat="median")
        res.add(**add, metric="error", value=p["error"], unit="1-SSIM", stat="mean")
        res.add(**add, metric="dominated", value=float(p["dominated"]), unit="1", stat="system")
        res.add(**add, metric="dominated", value=float(p["dominated_combined"]), unit="1", stat="combined")


def bench(frequency: Bench) -> Bench:
    """``bench pareto``, running ``frequency`` (``bench frequency``) where ``--from-dir`` holds no frequency.csv
    (:mod:`bench.registry` hands it in: benches import no bench)."""
    return Bench(
        "pareto",
        ParetoConfig,
        partial(measure, frequency=frequency),
        help="Error against run time over every speed/quality knob of both systems (per GI map and per frame), fronts "
        "with dominated points marked, the best configuration per time budget; reuses convergence/frequency CSVs under "
        "--from-dir.",
        dashboard=Section("pareto", "Error against run time (Pareto fronts)", 70),
        readme=Block("Error against run time", 30, make="bench pareto --from-dir {out} --out {out}/pareto"),
        parts=PARTS,
        needs=("run_time", "error"),
    )
