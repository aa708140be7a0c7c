"""Randomised scenes (``gicore-dataset --random N``): training data that covers what users bring, not five colours.

Scene ``i`` of seed ``s`` is a pure function of (s, i) (:func:`draw_scene`): asking for more scenes later draws the
same first ones again. Each scene draws, within :data:`RANGES`: the environment (white plane or Cornell box); 1-3
objects, each a shape of :mod:`gicore.shapes` (primitives with sharp edges, thin shells, the procedural anatomy
deformed) with its numbers, tilt, height, place on the floor and turn; each object's albedo from hue, saturation
and value drawn over the whole range; the point light's rest position, intensity and swing; and a camera orbit that
frames the objects. The meshes are written beside the scene's dataset (``<out>/<name>/meshes/``) and the spec
names them, so a dataset's ``meta.json`` holds the scene as any other. :func:`write_card` writes what was drawn:
``random_scenes.json`` (every draw, with the ranges) and ``random_scenes.md`` (a table), the dataset's card.
"""

from __future__ import annotations

import colorsys
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from gicore.fileio import atomic_write_bytes
from gicore.geometry import BOX_HALF
from gicore.scene import SceneSpec
from gicore.shapes import Shape

#: Every range a draw comes from (uniform unless said), as the card records them.
RANGES: dict[str, Any] = {
    "environment": ["white_plane", "cornell_box"],
    "objects": [1, 3],
    "shape": {"anatomy": 0.3, "box": 0.1, "plate": 0.06, "cylinder": 0.08, "cone": 0.06, "capsule": 0.08,
              "ellipsoid": 0.08, "torus": 0.08, "tube": 0.08, "bowl": 0.08},
    "hue": [0.0, 1.0],
    "saturation": [0.0, 1.0],
    "value": [0.05, 0.95],
    "height": {"white_plane": [0.4, 1.5], "cornell_box": [0.4, 1.3]},
    "tilt_degrees": [-40.0, 40.0],
    "light_position": {"white_plane": [[-1.5, 1.8, -1.5], [1.5, 3.2, 1.5]],
                       "cornell_box": [[-0.5, 1.9, -0.5], [0.5, 2.2, 0.6]]},
    "light_intensity": {"white_plane": [6.0, 18.0], "cornell_box": [4.0, 12.0]},
    "light_amplitude": {"white_plane": [1.0, 0.4], "cornell_box": [0.6, 0.15]},
}  # fmt: skip
#: Half the square of floor the objects stand on: the plane's (in view of the orbit) and the box's (off its walls).
FLOOR_HALF = {"white_plane": 0.6, "cornell_box": BOX_HALF - 0.45}


def _shape(rng: np.random.Generator, kind: str) -> Shape:
    """A shape of ``kind`` with its numbers drawn (the ranges of each kind's own proportions)."""
    u = rng.uniform
    params: dict[str, Any] = {
        "box": lambda: {"x": u(0.3, 1.0), "y": u(0.3, 1.0), "z": u(0.3, 1.0)},
        "plate": lambda: {"x": u(0.6, 1.0), "y": u(0.03, 0.06), "z": u(0.4, 0.9)},
        "cylinder": lambda: {"radius": u(0.15, 0.5)},
        "cone": lambda: {"radius": u(0.2, 0.6)},
        "capsule": lambda: {"radius": u(0.15, 0.45), "length": u(0.3, 1.2)},
        "ellipsoid": lambda: {"x": u(0.3, 1.0), "y": u(0.3, 1.0), "z": u(0.3, 1.0)},
        "torus": lambda: {"minor": u(0.15, 0.4)},
        "tube": lambda: {"radius": u(0.2, 0.5), "wall": u(0.02, 0.05), "height": u(0.4, 1.2)},
        "bowl": lambda: {"thickness": u(0.02, 0.06), "opening": u(60.0, 110.0)},
        "anatomy": lambda: {
            "organ": str(rng.choice(["lung", "digestive", "vessels"])),
            "seed": int(rng.integers(100, 1_000_000)),
            "scale": [round(float(s), 4) for s in u(0.7, 1.3, 3)],
            "twist": u(-45.0, 45.0),
            "bend": u(-0.4, 0.4),
        },
    }[kind]()
    rounded = {k: round(float(v), 4) if isinstance(v, float) else v for k, v in params.items()}
    tilt = (0.0, 0.0) if kind == "anatomy" else tuple(round(float(t), 2) for t in u(*RANGES["tilt_degrees"], 2))
    return Shape(kind, rounded, tilt)  # type: ignore[arg-type]


def _albedo(rng: np.random.Generator) -> tuple[list[float], list[float]]:
    """(hue, saturation, value) drawn over :data:`RANGES` and the RGB albedo they make."""
    hsv = [float(rng.uniform(*RANGES[k])) for k in ("hue", "saturation", "value")]
    return [round(c, 4) for c in hsv], [round(c, 4) for c in colorsys.hsv_to_rgb(*hsv)]


def _place(rng: np.random.Generator, radii: list[float], half: float) -> list[tuple[float, float]]:
    """Floor positions for objects of footprint ``radii`` inside the square of ``half``, apart where they fit."""
    placed: list[tuple[float, float]] = []
    for r in radii:
        room = max(half - r, 0.0)
        best, best_gap = (0.0, 0.0), -math.inf
        for _ in range(40):  # the candidate farthest from overlapping the others
            x, z = rng.uniform(-room, room, 2)
            gap = min((math.hypot(x - px, z - pz) - r - pr for (px, pz), pr in zip(placed, radii)), default=math.inf)
            if gap > best_gap:
                best, best_gap = (float(x), float(z)), gap
            if gap > 0.05:
                break
        placed.append(best)
    return placed


def draw_scene(seed: int, index: int, mesh_dir: Path) -> tuple[SceneSpec, dict[str, Any]]:
    """Scene ``index`` of ``seed``: its spec (meshes written into ``mesh_dir``) and what was drawn for it."""
    rng = np.random.default_rng([seed, index])
    name = f"random{seed}_{index:04d}"
    env = str(rng.choice(RANGES["environment"]))
    kinds, weights = zip(*RANGES["shape"].items())
    n = int(rng.integers(RANGES["objects"][0], RANGES["objects"][1] + 1))
    mesh_dir.mkdir(parents=True, exist_ok=True)
    objects, draws, radii = [], [], []
    for k in range(n):
        shape = _shape(rng, str(rng.choice(kinds, p=np.asarray(weights) / sum(weights))))
        mesh = shape.mesh().normalized(1.0)
        footprint = float(np.abs(mesh.vertices[:, [0, 2]]).max())  # per unit of height
        height = min(float(rng.uniform(*RANGES["height"][env])), FLOOR_HALF[env] / max(footprint, 1e-6))
        radii.append(footprint * height)
        hsv, rgb = _albedo(rng)
        path = mesh_dir / f"{name}_{k}.ply"
        mesh.save(path)
        objects.append({"name": f"object{k}", "mesh": str(path.absolute()), "height": round(height, 4),
                        "rotate_y": round(float(rng.uniform(-180, 180)), 2), "albedo": rgb})  # fmt: skip
        draws.append({"shape": shape.to_dict(), "albedo_hsv": hsv})
    for obj, (x, z) in zip(objects, _place(rng, radii, FLOOR_HALF[env])):
        obj["position"] = [round(x, 4), 0.0, round(z, 4)]
    top = max(o["height"] for o in objects)
    spec = {"name": name, "environment": env, "objects": objects, "light": _light(rng, env, top),
            "camera": _camera(rng, env, objects, radii)}  # fmt: skip
    return SceneSpec.from_dict(spec, source=name), {"name": name, "objects": draws}


def _light(rng: np.random.Generator, env: str, top: float) -> dict[str, Any]:
    """A point light over the scene, its lowest point of swing at least 0.3 above the tallest object's top."""
    low, high = RANGES["light_position"][env]
    amplitude = [round(float(rng.uniform(0.0, a)), 3) for a in RANGES["light_amplitude"][env]]
    x, y, z = rng.uniform(low, high)
    return {
        "position": [round(float(x), 3), round(max(float(y), top + 0.3 + amplitude[1]), 3), round(float(z), 3)],
        "intensity": round(float(rng.uniform(*RANGES["light_intensity"][env])), 3),
        "amplitude": amplitude,
        "period": [240.0, 330.0],
    }


def _camera(rng: np.random.Generator, env: str, objects: list[dict], radii: list[float]) -> dict[str, Any]:
    """An orbit that frames the objects: around their middle, at a distance that grows with their size (the
    Cornell box's through its open side, as the built-in scenes')."""
    top = max(o["height"] for o in objects)
    xs = [o["position"][0] for o in objects]
    zs = [o["position"][2] for o in objects]
    target = [round(float(np.mean(xs)), 3), round(0.5 * top, 3), round(float(np.mean(zs)), 3)]
    if env == "cornell_box":
        return {"target": target, "radius": round(float(rng.uniform(1.9, 2.2)), 3),
                "height": round(float(rng.uniform(0.9, 1.4)), 3), "azimuth_range": 70.0}  # fmt: skip
    spread = max(math.hypot(x - target[0], z - target[2]) + r for x, z, r in zip(xs, zs, radii))
    size = max(top, 2.0 * spread)
    return {
        "target": target,
        "radius": round(size * float(rng.uniform(0.8, 1.1)) + 0.25, 3),
        "height": round(size * float(rng.uniform(0.45, 0.8)) + 0.15, 3),
    }


def draw_scenes(seed: int, count: int, out: Path) -> list[SceneSpec]:
    """Scenes 0 .. ``count - 1`` of ``seed``, their meshes written under ``out/<name>/meshes/``, and their card
    (:func:`write_card`) in ``out``."""
    drawn = [draw_scene(seed, i, out / f"random{seed}_{i:04d}" / "meshes") for i in range(count)]
    write_card(out, seed, drawn)
    return [spec for spec, _ in drawn]


def write_card(out: Path, seed: int, drawn: list[tuple[SceneSpec, dict[str, Any]]]) -> None:
    """``random_scenes.json`` (the seed, :data:`RANGES`, and per scene its spec and draws) and ``random_scenes.md``
    (one line per object) in ``out``."""
    scenes = [draws | {"spec": spec.to_dict()} for spec, draws in drawn]
    doc = {"seed": seed, "count": len(drawn), "ranges": RANGES, "scenes": scenes}
    atomic_write_bytes(out / "random_scenes.json", json.dumps(doc, indent=1).encode())
    lines = [
        f"# Randomised scenes: seed {seed}, {len(drawn)} scenes",
        "",
        "Drawn by `gicore-dataset --random` (gicore.scene_draws) from the ranges in random_scenes.json; each scene's "
        "dataset is the folder of its name.",
        "",
        "| scene | environment | light (position, intensity) | object | shape | height | albedo (HSV) |",
        "|---|---|---|---|---|---|---|",
    ]
    for spec, draws in drawn:
        light = f"{list(spec.light.position)}, {spec.light.intensity:g}"
        for obj, draw in zip(spec.objects, draws["objects"]):
            hsv = ", ".join(f"{c:.2f}" for c in draw["albedo_hsv"])
            shape = " ".join([draw["shape"]["kind"], draw["shape"]["params"].get("organ", "")]).strip()
            cells = [spec.name, spec.environment, light, obj.name, shape, f"{obj.height:.2f}", hsv]
            lines.append("| " + " | ".join(cells) + " |")
    atomic_write_bytes(out / "random_scenes.md", ("\n".join(lines) + "\n").encode())
