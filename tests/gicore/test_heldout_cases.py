"""The held-out generalisation check's parts: the object metrics on images with known answers, the case set (held
out from the randomised draws' ranges), and the targets' verdicts."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gicore.heldout_cases import HELDOUT_COLOURS, SHAPES, TARGETS, TRAINING_COLOUR, Case, case_spec, cases, verdicts
from gicore.metrics import chroma_error, object_mask, object_psnr
from gicore.scene_draws import RANGES


def test_object_mask_psnr_and_chroma_have_their_known_values() -> None:
    albedo = np.full((8, 8, 3), 0.8)  # the white floor ...
    albedo[2:6, 2:6] = (0.4, 0.6, 0.8)  # ... and the object
    albedo[0, 0] = 0.0  # background
    mask = object_mask(albedo + 0.004, (0.4, 0.6, 0.8))  # float16 rounding is within the tolerance
    assert mask.sum() == 16 and mask[2:6, 2:6].all()
    gt = np.full((8, 8, 3), (0.3, 0.4, 0.5))
    off = gt.copy()
    off[mask] += 0.1  # an error of 0.1 on the object's pixels only
    assert object_psnr(off, gt, mask) == pytest.approx(20.0)
    assert object_psnr(gt, gt, mask) == math.inf and math.isnan(object_psnr(gt, gt, np.zeros((8, 8), bool)))
    assert chroma_error(0.5 * gt, gt, mask) == pytest.approx(0.0, abs=1e-12)  # darker, the same colour
    swapped = gt[..., ::-1]  # (0.5, 0.4, 0.3) against (0.3, 0.4, 0.5): chromaticities differ by 1/6 twice
    assert chroma_error(swapped, gt, mask) == pytest.approx(2 * 0.2 / 1.2)
    assert math.isnan(chroma_error(gt, 0.1 * gt, mask))  # nothing the GT lights


def test_cases_hold_out_colours_and_shape_parameters_from_the_training_draws(tmp_path: Path) -> None:
    all_cases = cases()
    held_out = [c for c in all_cases if not c.training_colour]
    assert len(held_out) >= 12 and len(held_out) == len(SHAPES) * len(HELDOUT_COLOURS)
    assert len({c.name for c in all_cases}) == len(all_cases)
    drawn = {"torus": ("minor", [0.15, 0.4]), "capsule": ("length", [0.3, 1.2]), "box": ("x", [0.3, 1.0])}
    for _, shape, _, _ in SHAPES:
        if shape.kind in drawn:
            key, (lo, hi) = drawn[shape.kind]
            assert not lo <= shape.params[key] <= hi, shape  # outside what the randomised scenes draw
    assert next(s for _, s, _, _ in SHAPES if s.kind == "anatomy").params["seed"] < 100  # drawn seeds start there
    assert RANGES["shape"]["anatomy"] > 0  # ... and the organs are drawn too
    spec = case_spec(Case("box", *HELDOUT_COLOURS[0]), tmp_path)
    assert spec.environment == "white_plane" and spec.objects[0].albedo == HELDOUT_COLOURS[0][1]
    assert Path(spec.objects[0].mesh).is_file()


def test_verdicts_apply_each_target() -> None:
    good = {"object_psnr": 27.0, "gain_db": 9.0, "chroma_error": 0.03}
    scores = {Case("torus", *TRAINING_COLOUR).name: good, "torus_blue_grey": good | {"object_psnr": 23.5},
              "torus_green": {"object_psnr": 20.0, "gain_db": 5.0, "chroma_error": 0.08}}  # fmt: skip
    rows = verdicts(scores)
    kind = {"gain": "gain over DI", "chroma": "chroma", "drop": "training colour"}
    by = {(r["case"], k): r for r in rows for k, words in kind.items() if words in r["target"]}
    assert len(by) == len(rows) == 2 + 3 + 3  # the training colour's own case has no colour drop
    assert by["torus_pink", "gain"]["met"] and by["torus_pink", "chroma"]["met"]
    assert by["torus_blue_grey", "gain"]["met"] and by["torus_blue_grey", "chroma"]["met"]
    assert not by["torus_blue_grey", "drop"]["met"] and by["torus_blue_grey", "drop"]["measured"] == pytest.approx(3.5)
    assert not any(by["torus_green", k]["met"] for k in kind) and by["torus_green", "drop"]["measured"] == 7.0
    scores["torus_blue_grey"]["object_psnr"] = 24.5
    assert next(r for r in verdicts(scores) if r["case"] == "torus_blue_grey" and "training" in r["target"])["met"]
    assert TARGETS == {"gain_db": 6.0, "chroma_error": 0.05, "colour_drop_db": 3.0}
