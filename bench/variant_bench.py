"""`bench variants`: the server's bake on each Mitsuba variant, against the CPU's.

The same GI maps (the scene's fly-through cameras of ``maps`` frames, its light schedule, ``spp``, the render
seeds of ``--seed``) are baked once per device of ``variants`` (``GIGAN_MITSUBA_VARIANT=cpu`` or ``cuda``), each
by its own ``cloudbaking-prebake`` process, since a process chooses its variant once (:mod:`gicore.mitsuba_variant`),
and each denoised by its variant's denoiser (OIDN on the CPU, OptiX on CUDA), as the server bakes them; stored as
``exr-half``, whose float16 is finer than tone-mapped SSIM resolves. The first variant's maps are the reference,
or, with ``--reference DIR``, the first variant's maps of an earlier run's ``--out`` (a CPU bake made on a machine
with pyoidn, carried to a GPU machine without it); every variant of this run is then baked and compared.

Rows per variant (``system``: the device; config: the Mitsuba ``variant`` and ``denoiser`` it ran, ``source``
``here`` or ``reference``): ``mean`` (linear radiance over every map), ``bake`` (render + denoise per map, ms, as
the payload header records it: median, p95 and n over the maps after the first; the first's, with the kernels'
compile, ``stat = first``); for each variant compared with the reference: ``ssim`` of its tone-mapped maps
against the reference's of the same view (``mean``, ``min``), ``mean_ratio`` (its mean over the reference's), and
``target_met``: SSIM >= :data:`SSIM_TARGET` on every map (a miss is reported, not an error).
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.processes import BIN
from bench.runner import Bench, Section
from gicore import option_groups
from gicore.error_policy import UserError
from gicore.mitsuba_variant import VARIANT_ENV, VariantChoice, machine_choice
from gicore.present.declarations import Column, Rows, Table, first, matches, unique
from gicore.results import Results, read_provenance, read_rows

#: SSIM a variant's maps reach against the reference's, every map.
SSIM_TARGET = 0.98
#: The devices a run may bake on (``GIGAN_MITSUBA_VARIANT``; ``auto`` is one of them on a given machine).
VARIANTS = ("cpu", "cuda")
CODEC = "exr-half"
#: Each variant's bake under ``--out``: ``<RUNS>/<variant>/store`` (the GI tree) and its ``console.txt``.
RUNS = "variants_runs"
#: Settings a reference run must share with this one to have baked the same maps (also: the scene's spec and the
#: seed, checked in :func:`measure`).
SAME_MAPS = ("resolution", "spp", "maps")


@dataclass(frozen=True)
class VariantsConfig:
    """Which maps are baked, and on which devices (see the module docstring)."""

    scenes: tuple[str, ...] = option_groups.scenes(one=True, note="the one whose maps are baked")
    resolution: int = option_groups.resolution(note="of the maps")
    spp: int = option_groups.spp(note="of each map, then its variant's denoiser")
    #: Maps per variant: the GI cameras of as many frames along the scene's fly-through.
    maps: int = field(default=5, metadata={"min": 1, "max": 1000})
    #: Devices baked on, each in its own process: cpu and/or cuda; the first is the reference (without --reference).
    variants: tuple[str, ...] = field(default=VARIANTS, metadata={"min_len": 1})
    #: An earlier run's --out whose first variant's maps are the reference; every variant here is then baked.
    reference: Path | None = None

    @classmethod
    def quick(cls) -> VariantsConfig:
        return cls(resolution=128, spp=16, maps=3)

    def check(self) -> None:
        for name in self.variants:
            if name not in VARIANTS:
                raise UserError(f"--variants {name!r} is not a device", f"use some of {', '.join(VARIANTS)}")
        if len(set(self.variants)) != len(self.variants):
            raise UserError(f"--variants {','.join(self.variants)} names a device twice", "name each once")
        for name in self.variants:
            choice(name)
        if self.reference is not None:
            reference_settings(self)


def choice(device: str) -> VariantChoice:
    """The :class:`gicore.mitsuba_variant.VariantChoice` a process with ``GIGAN_MITSUBA_VARIANT=device`` makes on
    this machine; a device that cannot run here is a one-line user error before anything is baked."""
    try:
        made = machine_choice(device)
    except UserError as exc:
        raise UserError(
            f"--variants {device}: {exc.what}", "bake it on a machine that has one, or leave it out"
        ) from None
    if made.needs_pyoidn and importlib.util.find_spec("pyoidn") is None:
        raise UserError(
            f"--variants {device}: its denoiser, OIDN, needs pyoidn, which is not installed",
            "pip install pyoidn, or give --reference the --out of a run made where it is",
        )
    return made


def reference_settings(cfg: VariantsConfig) -> dict[str, Any]:
    """The provenance of the ``--reference`` run, checked to have baked maps of ``cfg``'s size, spp and count."""
    prov = read_provenance(Path(cfg.reference or "") / "variants.csv") or {}
    settings = prov.get("settings")
    if not isinstance(settings, dict):
        raise UserError(
            f"--reference {cfg.reference}: no variants.provenance.json there", "give the --out of a bench variants run"
        )
    for name in SAME_MAPS:
        if settings.get(name) != json.loads(json.dumps(getattr(cfg, name))):
            raise UserError(
                f"--reference {cfg.reference} baked {name} {settings.get(name)}, not {getattr(cfg, name)}",
                f"give the same --{name}, or bake the reference anew",
            )
    return prov


def reference_bake(cfg: VariantsConfig, seed: int, store: Path, scene: str) -> Bake:
    """The reference run's maps in ``store``, checked to be of this run's scene spec and seed."""
    from baseline_cloudbaking.bake import spec_sha
    from baseline_cloudbaking.store import GITree
    from gicore.scene import load_scene

    prov = reference_settings(cfg)
    with GITree(store) as tree:
        registered = tree.index.scene(Path(scene).stem)
    if registered is None or registered[0] != spec_sha(load_scene(scene)) or prov.get("seed") != seed:
        raise UserError(
            f"--reference {cfg.reference} holds no maps of this {scene} at --seed {seed}",
            "give the same scene spec and --seed, or bake the reference anew",
        )
    return read_bake(store, Path(scene).stem)


@dataclass(frozen=True)
class Bake:
    """One variant's maps, in fly-through order: each map's GI camera, linear GI and bake time (ms)."""

    cameras: list[dict[str, Any]]
    maps: list[np.ndarray]
    bake_ms: list[float]


def bake(cfg: VariantsConfig, device: str, folder: Path, seed: int) -> Bake:
    """Bake ``cfg``'s maps with ``GIGAN_MITSUBA_VARIANT=device`` in a ``cloudbaking-prebake`` process of their own
    into ``folder / "store"`` (its output in ``console.txt``). Tolerance 0: every frame gets its own map."""
    scene = cfg.scenes[0]
    argv = [str(BIN / "cloudbaking-prebake"), scene, "--store", str(folder / "store"), "--frames", str(cfg.maps),
            "--codec", CODEC, "--resolution", str(cfg.resolution), "--spp", str(cfg.spp), "--seed", str(seed),
            "--tolerance-p", "0", "--tolerance-deg", "0", "--workers", "1"]  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(argv, capture_output=True, text=True, env=os.environ | {VARIANT_ENV: device}, check=False)
    (folder / "console.txt").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        said = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
        why = said[-1].removeprefix("error: ") if said else f"exit status {proc.returncode}"
        raise UserError(f"the {device} bake failed ({why})", f"see {folder / 'console.txt'}")
    return read_bake(folder / "store", Path(scene).stem)


def read_bake(store: Path, scene: str) -> Bake:
    """The maps of ``scene`` in the GI tree at ``store``, in the order they were baked."""
    from baseline_cloudbaking.protocol import decode_payload
    from baseline_cloudbaking.store import GITree

    with GITree(store) as tree:
        payloads = [decode_payload(tree.payload_by_sha(e.sha)) for e in sorted(tree.entries(scene), key=lambda e: e.id)]
    times = [p.header["bake_ms"] for p in payloads]
    return Bake(
        [p.header["camera"] for p in payloads], [p.gi for p in payloads], [t["render"] + t["denoise"] for t in times]
    )


def compare(maps: list[np.ndarray], reference: Bake, cameras: list[dict[str, Any]]) -> list[float]:
    """Each map's SSIM (tone-mapped) against the reference's map of the same GI camera."""
    from gicore.metrics import ssim
    from gicore.tonemap import tonemap

    if len(cameras) != len(reference.cameras) or not all(map(same_camera, cameras, reference.cameras)):
        raise RuntimeError("the variants baked different GI cameras: their maps cannot be compared")
    return [ssim(tonemap(a), tonemap(b)) for a, b in zip(maps, reference.maps, strict=True)]


def same_camera(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Two GI cameras alike to rounding (a reference may come from another machine's numpy)."""
    return a.keys() == b.keys() and all(np.allclose(a[k], b[k], rtol=1e-9, atol=1e-9) for k in a)


def record(res: Results, scene: str, device: str, baked: Bake, config: dict[str, Any]) -> None:
    """A variant's mean and bake-time rows."""
    res.add(system=device, scene=scene, metric="mean", value=mean_of(baked), unit="1", stat="mean", **config)
    res.add(system=device, scene=scene, metric="bake", value=baked.bake_ms[0], unit="ms", stat="first", **config)
    if len(baked.bake_ms) > 1:
        res.add_timing(
            system=device, scene=scene, metric="bake", samples_s=[t / 1e3 for t in baked.bake_ms[1:]], **config
        )


def measure(cfg: VariantsConfig, res: Results) -> None:
    from gicore.scene import load_scene

    name = load_scene(cfg.scenes[0]).name
    common = {"resolution": cfg.resolution, "spp": cfg.spp, "maps": cfg.maps, "codec": CODEC}
    against, here, reference, ref_config = the_reference(cfg, res, common)
    record(res, name, against, reference, ref_config)
    for device in here:
        baked, made = bake(cfg, device, res.out / RUNS / device, res.seed), choice(device)
        config = common | {"variant": made.variant, "denoiser": made.denoiser, "source": "here", "against": against}
        record(res, name, device, baked, config)
        scores = compare(baked.maps, reference, baked.cameras)
        for stat, value in (("mean", float(np.mean(scores))), ("min", min(scores))):
            res.add(system=device, scene=name, metric="ssim", value=value, unit="1", stat=stat, **config)
        ratio = mean_of(baked) / mean_of(reference)
        res.add(system=device, scene=name, metric="mean_ratio", value=ratio, unit="1", **config)
        met = min(scores) >= SSIM_TARGET
        verdict = {"value": float(met), "unit": "1", "stat": "target_met", "target": SSIM_TARGET}
        res.add(system=device, scene=name, metric="ssim", **verdict, **config)
        print(
            f"variants: {device} ({made.variant}, {made.denoiser}) against {against} ({ref_config['variant']}, "
            f"{ref_config['denoiser']}): SSIM min {min(scores):.4f} over {len(scores)} maps, target >= "
            f"{SSIM_TARGET}: {'met' if met else 'NOT met'}; mean radiance ratio {ratio:.4f}",
            flush=True,
        )


def the_reference(
    cfg: VariantsConfig, res: Results, common: dict[str, Any]
) -> tuple[str, tuple[str, ...], Bake, dict[str, Any]]:
    """The reference's device, the devices compared with it, its maps and its rows' config: the first variant
    baked here, or the ``--reference`` run's first (its run recorded in the provenance)."""
    if cfg.reference is None:
        against = cfg.variants[0]
        made = choice(against)
        reference = bake(cfg, against, res.out / RUNS / against, res.seed)
        config = common | {"variant": made.variant, "denoiser": made.denoiser, "source": "here"}
        return against, cfg.variants[1:], reference, config
    prov = reference_settings(cfg)
    against = prov["settings"]["variants"][0]
    reference = reference_bake(cfg, res.seed, cfg.reference / RUNS / against / "store", cfg.scenes[0])
    ran = next(
        r
        for r in read_rows(cfg.reference / "variants.csv")
        if matches(r, "mean", "mean", source="here") and r["system"] == against
    )
    res.settings["reference_run"] = {k: prov.get(k) for k in ("run_id", "machine", "versions", "git")}
    config = common | {k: ran["config"][k] for k in ("variant", "denoiser")} | {"source": "reference"}
    return against, cfg.variants, reference, config


def mean_of(baked: Bake) -> float:
    """Mean linear radiance over every map."""
    return float(np.mean([m.mean() for m in baked.maps]))


# -- what it shows ---------------------------------------------------------------------------------------------
def variant_rows(rows: Rows) -> list[dict[str, Any]]:
    """One line per bake (a device here, or the reference run's): what ran, its mean, its SSIM and mean against
    the reference, its bake times."""
    out = []
    for device, source in unique((r["system"], r["config"]["source"]) for r in rows if matches(r, "mean", "mean")):
        mine = [r for r in rows if r["system"] == device and r["config"]["source"] == source]
        met = first(mine, "ssim", "target_met")
        out.append(
            {"device": device, **next(r["config"] for r in mine if matches(r, "mean", "mean"))}
            | {k: first(mine, m, s) for k, (m, s) in VALUES.items()}
            | ({} if met is None else {"met": "met" if met else "**not met**"})
        )
    return out


#: The table's values: field -> (metric, stat).
VALUES = {
    "mean": ("mean", "mean"),
    "ratio": ("mean_ratio", "value"),
    "ssim": ("ssim", "mean"),
    "ssim_min": ("ssim", "min"),
    "bake": ("bake", "median"),
    "first": ("bake", "first"),
}


def _caption(rows: Rows) -> str:
    c = rows[0]["config"]
    return (
        f"{rows[0]['scene']}, {c['maps']} maps along the fly-through at {c['resolution']}², {c['spp']} spp then "
        f"each variant's denoiser, stored as {c['codec']}; SSIM of the tone-mapped maps against the reference's "
        f"(target >= {SSIM_TARGET} on every map); bake = render + denoise per map (median after the first)."
    )


PARTS = (
    Table(
        variant_rows,
        (
            Column("device", "{device}"),
            Column("Mitsuba variant, denoiser", "{variant}, {denoiser}[[ ({source})]]"),
            Column("mean radiance (/ reference)", "{mean:.4g}[[ ({ratio:.4f})]]"),
            Column("SSIM mean (min)", "{ssim:.4f} ({ssim_min:.4f})"),
            Column(f"SSIM >= {SSIM_TARGET}", "{met}"),
            Column("bake ms: median (first)", "{bake:.1f} ({first:.0f})"),
        ),
        title="The server's bake on each Mitsuba variant",
        caption=_caption,
        where="dashboard",
    ),
)

BENCH = Bench(
    "variants",
    VariantsConfig,
    measure,
    help="The server's bake on each Mitsuba variant (GIGAN_MITSUBA_VARIANT=cpu/cuda, one process each): mean, "
    f"SSIM against the CPU bake (target >= {SSIM_TARGET}) and bake time per map.",
    dashboard=Section("variants", "Mitsuba variants: the server's bake on each device", 13),
    parts=PARTS,
    needs=("mean", "bake"),
)
