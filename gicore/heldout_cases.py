"""The held-out generalisation check's cases and targets (``bench quality --generalisation``): shapes and colours
that no training data draws, each on the white plane, and what a model must reach on each.

A case is a shape of :mod:`gicore.shapes` with numbers outside the ranges :mod:`gicore.scene_draws` draws from (a
fatter torus, an exact sphere, a longer capsule, a wider box, an organ seed below the drawn ones) in one colour:
:data:`TRAINING_COLOUR` (the built-in scenes' pink, which the shipped model trained on) or one of
:data:`HELDOUT_COLOURS`. Its frames are a dataset (``gicore.dataset``: held-out frames only, camera paths of
:data:`HELDOUT_SEED`) rendered once into a folder and reused. :func:`verdicts` applies :data:`TARGETS` to the
scores: per case the object PSNR's gain over DI alone and the chroma error (``gicore.metrics``), and per held-out
colour the object PSNR against the same shape in the training colour.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gicore.dataset_cli import DatasetConfig, build_dataset
from gicore.scene import SceneSpec
from gicore.shapes import Shape

#: The camera paths' seed (the training data's are the user's --seed; the built-in scenes' held-out frames, 0, 1, 2).
HELDOUT_SEED = 7
#: Frames per case, and the GT's samples (denoised, as the built-in scenes' held-out frames).
FRAMES, SPP = 4, 64
TRAINING_COLOUR = ("pink", (0.8, 0.35, 0.3))
HELDOUT_COLOURS = (("blue_grey", (0.4, 0.6, 0.8)), ("green", (0.3, 0.7, 0.35)), ("yellow", (0.9, 0.8, 0.25)))
#: Shape, height, turn about y (degrees).
SHAPES: tuple[tuple[str, Shape, float, float], ...] = (
    ("torus", Shape("torus", {"minor": 0.45}, (50.0, 0.0)), 0.8, 0.0),
    ("sphere", Shape("ellipsoid", {"x": 1.0, "y": 1.0, "z": 1.0}), 0.9, 0.0),
    ("capsule", Shape("capsule", {"radius": 0.25, "length": 1.4}), 1.2, 0.0),
    ("box", Shape("box", {"x": 1.2, "y": 0.35, "z": 0.8}), 0.5, 30.0),
    ("organ", Shape("anatomy", {"organ": "digestive", "seed": 7, "scale": [1.1, 0.9, 1.1], "twist": 20.0,
                                "bend": -0.2}), 1.1, 0.0),
)  # fmt: skip
#: What a model must reach on every case: object PSNR gain over DI alone (dB, at least), chroma error (at most), and
#: a held-out colour's object PSNR against the same shape in the training colour (dB, at most this far below).
TARGETS = {"gain_db": 6.0, "chroma_error": 0.05, "colour_drop_db": 3.0}


@dataclass(frozen=True)
class Case:
    """One shape in one colour."""

    shape: str
    colour: str
    albedo: tuple[float, float, float]

    @property
    def name(self) -> str:
        return f"{self.shape}_{self.colour}"

    @property
    def training_colour(self) -> bool:
        return self.colour == TRAINING_COLOUR[0]


def cases() -> list[Case]:
    """Every shape in the training colour and in each held-out colour."""
    return [Case(s[0], colour, rgb) for s in SHAPES for colour, rgb in (TRAINING_COLOUR, *HELDOUT_COLOURS)]


def case_spec(case: Case, mesh_dir: Path) -> SceneSpec:
    """``case`` on the white plane under the plane scenes' moving light, its mesh written into ``mesh_dir``."""
    _, shape, height, turn = next(s for s in SHAPES if s[0] == case.shape)
    mesh_dir.mkdir(parents=True, exist_ok=True)
    path = mesh_dir / f"{case.shape}.ply"
    shape.mesh().save(path)
    obj = {"name": case.shape, "mesh": str(path.absolute()), "height": height, "rotate_y": turn, "albedo": case.albedo}
    spec = {
        "name": case.name,
        "environment": "white_plane",
        "objects": [obj],
        "light": {"position": [0.8, 2.6, 1.2], "intensity": 12.0, "amplitude": [1.0, 0.4], "period": [240.0, 330.0]},
        "camera": {"target": [0.0, 0.5 * height, 0.0], "radius": 1.0 + 0.6 * height, "height": 0.5 + 0.6 * height},
    }
    return SceneSpec.from_dict(spec, source=case.name)


def case_datasets(root: Path, resolution: int, frames: int = FRAMES) -> list[tuple[Case, Path]]:
    """Every case's dataset at ``resolution`` under ``root/<resolution>/<case>`` (rendered where missing)."""
    cfg = DatasetConfig(n_train=0, n_val=frames, resolution=resolution, spp=SPP, denoise=True, seed=HELDOUT_SEED)
    out = []
    for case in cases():
        folder = root / str(resolution) / case.name
        build_dataset(case_spec(case, folder / "meshes"), folder, cfg, progress=False)
        out.append((case, folder))
    return out


def verdicts(scores: dict[str, dict[str, float]]) -> list[dict[str, Any]]:
    """Each target on each case of ``scores`` (case name -> ``object_psnr``, ``gain_db``, ``chroma_error``): the
    target's words, what was measured and whether it was met."""
    out = []
    for case in cases():
        s = scores.get(case.name)
        if s is None:
            continue
        checks = [
            (f"object PSNR gain over DI alone >= {TARGETS['gain_db']:g} dB", s["gain_db"], s["gain_db"]
             >= TARGETS["gain_db"]),
            (f"chroma error <= {TARGETS['chroma_error']:g}", s["chroma_error"], s["chroma_error"]
             <= TARGETS["chroma_error"]),
        ]  # fmt: skip
        reference = scores.get(Case(case.shape, *TRAINING_COLOUR).name)
        if not case.training_colour and reference is not None:
            drop = reference["object_psnr"] - s["object_psnr"]
            words = f"object PSNR within {TARGETS['colour_drop_db']:g} dB of the {case.shape} in the training colour"
            checks.append((words, drop, drop <= TARGETS["colour_drop_db"]))
        out += [{"case": case.name, "target": t, "measured": float(m), "met": bool(ok)} for t, m, ok in checks]
    return out
