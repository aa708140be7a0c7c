"""`bench fov` (paper Fig. 9 and Fig. 8): the GI camera's field of view F_GI against the quality of the GI
map itself and of the map warped to a camera that has since turned or moved.

At several views along the camera path a GI map is made at the GI camera (FOV F_GI, same position and
orientation as the local camera) by the configured source -- the generator (``gi_source = "model"``) or
the path-traced GT stand-in, whose "quality" is only the noise floor of two independent renders -- and
compared with a path-traced GT at that camera (Fig. 9). Then the local camera (FOV ``local_fov``) turns
about the vertical axis or moves sideways by several amounts, the map is warped there by each method,
and the result is compared with the GT at the moved camera (Fig. 8). Without warping the best one can do
is paste a map made at the local FOV; that reference is reported too. The light stays where it was for
the map, so the error is the warp's and the FOV's alone.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from bench.common import WARP_LABELS, make_warp
from bench.exported_models import check_model_resolution
from bench.runner import FOV_DEGREES, Bench, Block, Figure, Part, Rows, Section, Table, need, pick
from bench.svg import Point, Series, XYChart
from gicore.camera import Camera
from gicore.results import Results, read_rows
from gigan_local.client import GI_SOURCES
from gigan_local.inference import DEFAULT_MODEL


@dataclass(frozen=True)
class FovConfig:
    """The parameter grid of one run."""

    #: Scene names or spec files.
    scenes: tuple[str, ...] = ("lung_plane",)
    #: Square resolution in pixels.
    resolution: int = 256
    #: GI-camera FOVs F_GI compared, degrees.
    gi_fovs: tuple[float, ...] = field(default=(60.0, 90.0, 120.0), metadata=FOV_DEGREES)
    #: FOV of the local (client) camera, degrees; at this F_GI the no-warping reference is scored too.
    local_fov: float = field(default=60.0, metadata=FOV_DEGREES)
    #: Frames along the camera path where GI maps are made (the views).
    base_frames: tuple[int, ...] = field(default=(0, 60, 120, 180, 240), metadata={"min": 0})
    #: Frames per full orbit of the camera path.
    orbit_frames: int = 300
    #: Camera turns after the GI map, degrees about the vertical axis.
    rotations: tuple[float, ...] = (5.0, 10.0, 20.0, 30.0)
    #: Sideways camera moves after the GI map, scene units.
    translations: tuple[float, ...] = (0.1, 0.2, 0.4)
    #: Warp methods compared.
    warps: tuple[Literal["structure", "pixel"], ...] = ("structure", "pixel")
    #: Samples per pixel of path-traced GT (the gt GI source and the evaluation GT).
    spp: int = 64
    #: Denoise the path-traced renders with OIDN.
    denoise: bool = True
    #: Where GI maps come from: the path-traced GT stand-in, or the generator (--model).
    gi_source: Literal[GI_SOURCES] = "gt"
    #: ONNX generator for --gi-source model (gigan-export output).
    model: Path = DEFAULT_MODEL

    @classmethod
    def quick(cls) -> FovConfig:
        return cls(resolution=128, base_frames=(0, 150), rotations=(5.0, 15.0, 30.0), translations=(0.1, 0.3), spp=16)

    def check(self) -> None:
        if self.gi_source == "model":
            check_model_resolution(self.model, self.resolution)


def turned(camera: Camera, degrees: float) -> Camera:
    """``camera`` turned about the vertical axis through its origin (positive: to the left)."""
    a = math.radians(degrees)
    d = np.subtract(camera.target, camera.origin)
    rot = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    return Camera(
        camera.origin,
        tuple(np.add(camera.origin, rot @ d)),
        camera.up,
        camera.fov,
        camera.near,
        camera.far,
        camera.width,
        camera.height,
    )


def moved(camera: Camera, distance: float) -> Camera:
    """``camera`` moved sideways (along its right vector) by ``distance``, looking the same way."""
    right = -camera.to_world()[:3, 0]  # Mitsuba's camera x points left
    shift = distance * right
    return Camera(
        tuple(np.add(camera.origin, shift)),
        tuple(np.add(camera.target, shift)),
        camera.up,
        camera.fov,
        camera.near,
        camera.far,
        camera.width,
        camera.height,
    )


def measure(cfg: FovConfig, res: Results) -> None:
    for scene in cfg.scenes:
        _measure_scene(cfg, res, scene)


def _measure_scene(cfg: FovConfig, res: Results, scene: str) -> None:
    from gicore.loop import render_gt, warp_view
    from gicore.metrics import ssim
    from gicore.paths import camera_path, frame_seed, light_position
    from gicore.render import Renderer
    from gicore.scene import load_scene
    from gicore.tonemap import tonemap
    from gigan_local.client import ClientConfig, make_gi_source

    seed = res.seed
    spec = load_scene(scene)
    renderer = Renderer(spec, cfg.resolution)
    source = make_gi_source(
        ClientConfig(
            scene=scene,
            resolution=cfg.resolution,
            gi_source=cfg.gi_source,
            model=cfg.model,
            spp=cfg.spp,
            denoise=cfg.denoise,
            seed=seed,
        ),
        renderer,
    )
    cams = camera_path(spec, cfg.orbit_frames, seed=seed, fov=cfg.local_fov, resolution=cfg.resolution)
    motions = [("rotation", r, "deg") for r in cfg.rotations] + [("translation", t, "units") for t in cfg.translations]
    warps = {m: make_warp(m, renderer) for m in cfg.warps}
    paste = make_warp("none", renderer)
    quality: dict[tuple, list[float]] = defaultdict(list)
    for b in cfg.base_frames:
        base = cams[b % cfg.orbit_frames]
        light = light_position(spec, b)
        moves = {}  # every moved camera with its tone-mapped GT, shared by all F_GI
        for kind, amount, _ in motions:
            cam = turned(base, amount) if kind == "rotation" else moved(base, amount)
            gt = tonemap(
                render_gt(renderer, cam, light, cfg.spp, frame_seed(seed, f"gt/{kind}/{amount}", b), cfg.denoise)
            )
            moves[kind, amount] = (cam, gt)
        for gi_fov in cfg.gi_fovs:
            gi = source.produce(base.with_fov(gi_fov), light, b)
            reference = render_gt(renderer, gi.camera, light, cfg.spp, frame_seed(seed, "gt/gi", b), cfg.denoise)
            quality["map", gi_fov].append(ssim(tonemap(gi.radiance), tonemap(reference)))
            for method, warp in warps.items():
                warp.bind(gi)
                for kind, amount, _ in motions:
                    cam, ref = moves[kind, amount]
                    _, image, valid = warp_view(warp, renderer, cam, light, seed=b)
                    quality[method, gi_fov, kind, amount].append(ssim(tonemap(image), ref))
                    quality["valid", method, gi_fov, kind, amount].append(float(valid.mean()))
            if gi_fov == cfg.local_fov:
                paste.bind(gi)
                for kind, amount, _ in motions:
                    cam, ref = moves[kind, amount]
                    image = warp_view(paste, renderer, cam, light, seed=b)[1]
                    quality["none", gi_fov, kind, amount].append(ssim(tonemap(image), ref))

    common = {
        "resolution": cfg.resolution,
        "local_fov": cfg.local_fov,
        "views": len(cfg.base_frames),
        "spp": cfg.spp,
        "gi_source": cfg.gi_source,
    }
    source_label = "generator" if cfg.gi_source == "model" else "GT stand-in"
    for gi_fov in cfg.gi_fovs:
        res.add(
            system=source_label,
            scene=spec.name,
            metric="ssim_gi_map",
            value=float(np.mean(quality["map", gi_fov])),
            unit="1",
            stat="mean",
            gi_fov=gi_fov,
            **common,
        )
        for method in (*cfg.warps, "none"):
            for kind, amount, unit in motions:
                if (method, gi_fov, kind, amount) not in quality:
                    continue
                cfg_row = common | {"gi_fov": gi_fov, "motion": kind, "amount": amount, "amount_unit": unit}
                res.add(
                    system=WARP_LABELS[method],
                    scene=spec.name,
                    metric="ssim_warped",
                    value=float(np.mean(quality[method, gi_fov, kind, amount])),
                    unit="1",
                    stat="mean",
                    **cfg_row,
                )
                if method != "none":
                    res.add(
                        system=WARP_LABELS[method],
                        scene=spec.name,
                        metric="valid_fraction",
                        value=float(np.mean(quality["valid", method, gi_fov, kind, amount])),
                        unit="1",
                        stat="mean",
                        **cfg_row,
                    )


def plot(csv_path: Path, out_dir: Path) -> list[Path]:
    """Fig. 9 (GI-map SSIM against F_GI) and Fig. 8 (warped SSIM, and the share of the frame the GI map
    covers, against camera motion; one line per scene, method and F_GI)."""
    from gicore.plotting import plt, save

    rows = read_rows(csv_path)
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, 4, figsize=(19, 4.2))
    for scene in scenes:
        maps = sorted(
            (r["config"]["gi_fov"], r["value"]) for r in rows if r["metric"] == "ssim_gi_map" and r["scene"] == scene
        )
        axes[0].plot(*zip(*maps), "-o", label=scene)
    axes[0].set_xlabel("GI-camera FOV F_GI [deg]")
    axes[0].set_ylabel(f"SSIM of the GI map ({next(r['system'] for r in rows if r['metric'] == 'ssim_gi_map')})")
    panels = (
        ("rotation", "ssim_warped", "SSIM of the warped GI vs GT"),
        ("translation", "ssim_warped", "SSIM of the warped GI vs GT"),
        ("rotation", "valid_fraction", "frame covered by the GI map"),
    )
    for ax, (kind, metric, label) in zip(axes[1:], panels):
        sel = [r for r in rows if r["metric"] == metric and r["config"]["motion"] == kind]
        for scene in scenes:
            for system, style in zip(WARP_LABELS.values(), ("-o", "--s", ":^")):
                for gi_fov in sorted({r["config"]["gi_fov"] for r in sel}):
                    pts = sorted(
                        (r["config"]["amount"], r["value"])
                        for r in sel
                        if (r["scene"], r["system"], r["config"]["gi_fov"]) == (scene, system, gi_fov)
                    )
                    if pts:
                        label = (
                            f"{system}, F_GI {gi_fov:g}°"
                            if len(scenes) == 1
                            else f"{scene}: {system}, F_GI {gi_fov:g}°"
                        )
                        ax.plot(*zip(*pts), style, ms=4, label=label)
        ax.set_xlabel(f"camera {kind} [{next((r['config']['amount_unit'] for r in sel), '')}]")
        ax.set_ylabel(label)
    axes[2].legend(fontsize=6)
    for ax in axes:
        ax.grid(alpha=0.3)
    if len(scenes) > 1:
        axes[0].legend(fontsize=7)
    fig.suptitle("GI-camera FOV: GI-map quality (Fig. 9) and warping after camera motion (Fig. 8)")
    return [save(fig, out_dir / "fov.png")]


# -- bench report: the dashboard's section and the README's block ------------------------------------------
def table(rows: Rows) -> str:
    """Fig. 9 as Markdown: per scene and GI-camera FOV, the GI map's SSIM and each warp's SSIM (and the share of
    pixels the map covers), each the mean over every camera motion measured."""
    need(rows, "ssim_gi_map", "ssim_warped")
    warped = pick(rows, "ssim_warped")
    systems = list(dict.fromkeys(r["system"] for r in warped))
    source = ", ".join(dict.fromkeys(r["system"] for r in pick(rows, "ssim_gi_map")))
    motions = []
    for motion in dict.fromkeys(r["config"]["motion"] for r in warped):
        sel = [r["config"] for r in warped if r["config"]["motion"] == motion]
        amounts = ", ".join(dict.fromkeys(f"{c['amount']:g}" for c in sel))
        motions.append(f"{motion} {amounts} {sel[0]['amount_unit']}")
    lines = [
        f"GI maps: {source}. Warped: the mean over {'; '.join(motions)}; in brackets, the share of pixels the map "
        "covers.",
        "",
        "| scene | F_GI | SSIM of the GI map | " + " | ".join(f"SSIM warped: {s}" for s in systems) + " |",
        "|---" * (3 + len(systems)) + "|",
    ]
    for scene, fov in dict.fromkeys(
        (r["scene"], r["config"]["gi_fov"]) for r in rows if r["metric"] in ("ssim_gi_map", "ssim_warped")
    ):

        def mean(metric: str, system: str | None = None) -> float | None:
            vs = [
                r["value"]
                for r in pick(rows, metric)
                if (r["scene"], r["config"]["gi_fov"]) == (scene, fov) and system in (None, r["system"])
            ]
            return sum(vs) / len(vs) if vs else None

        cells = []
        for s in systems:
            ssim, covered = mean("ssim_warped", s), mean("valid_fraction", s)
            cells.append("—" if ssim is None else f"{ssim:.3f}" + ("" if covered is None else f" ({covered:.0%})"))
        gi_map = mean("ssim_gi_map")
        lines.append(
            f"| {scene} | {fov:g}° | {'—' if gi_map is None else f'{gi_map:.3f}'} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines)


def dashboard_section(rows: Rows) -> list[Part]:
    """The GI map's SSIM against F_GI per scene, the warped SSIM against each camera motion, then the table."""
    need(rows, "ssim_gi_map", "ssim_warped")
    maps = [
        Series(
            scene,
            [
                Point(
                    r["config"]["gi_fov"],
                    r["value"],
                    f"{scene}, F_GI {r['config']['gi_fov']:g}°: SSIM {r['value']:.4f}",
                )
                for r in pick(rows, "ssim_gi_map")
                if r["scene"] == scene
            ],
        )
        for scene in dict.fromkeys(r["scene"] for r in pick(rows, "ssim_gi_map"))
    ]
    figures = [
        XYChart(
            maps,
            "GI-camera FOV F_GI [°]",
            "SSIM of the GI map vs GT",
            caption=f"Source: {pick(rows, 'ssim_gi_map')[0]['system']}.",
        )
    ]
    for motion in dict.fromkeys(r["config"]["motion"] for r in pick(rows, "ssim_warped")):
        sel = [r for r in pick(rows, "ssim_warped") if r["config"]["motion"] == motion]
        lines = []
        for system, gi_fov in dict.fromkeys((r["system"], r["config"]["gi_fov"]) for r in sel):
            name = f"{system}, F_GI {gi_fov:g}°"
            tip = "{name}, {motion} {amount:g} {unit}: SSIM {value:.4f}"
            pts = [
                Point(
                    c["amount"],
                    r["value"],
                    tip.format(name=name, motion=motion, amount=c["amount"], unit=c["amount_unit"], value=r["value"]),
                )
                for r in sel
                if (r["system"], (c := r["config"])["gi_fov"]) == (system, gi_fov)
            ]
            lines.append(Series(name, pts))
        figures.append(
            XYChart(lines, f"camera {motion} [{sel[0]['config']['amount_unit']}]", "SSIM of the warped GI vs GT")
        )
    return [Figure(tuple(figures)), Table(table(rows))]


def readme_block(rows: Rows) -> list[Table]:
    """The same table as the dashboard's."""
    return [Table(table(rows))]


BENCH = Bench(
    "fov",
    FovConfig,
    measure,
    plot,
    help="Fig. 9 and Fig. 8: GI-camera FOV against GI-map quality and warped quality after camera motion.",
    dashboard=Section("fig9", "Fig. 9: GI-camera FOV", 60, dashboard_section),
    readme=Block("GI-camera FOV, Fig. 9", 70, readme_block),
)
