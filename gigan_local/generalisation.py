"""The held-out generalisation check of exported models (``bench quality --generalisation``): each model and DI alone
on the cases of :mod:`gicore.heldout_cases`, scored on the object's own pixels and against the targets.

Per model and case, over the case's frames (pooled): the object PSNR (the pixels whose G-buffer albedo is the
object's, :func:`gicore.metrics.object_mask`), its gain over DI alone on the same pixels, the chroma error over the
lit object pixels, and the whole frame's SSIM, PSNR, RMSE and LF error (which the floor dominates). All on
tone-mapped images, each model run as the client runs it (:meth:`gigan_local.inference.GIModel.predict`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gicore.dataset import frame_paths, load_frame, read_meta
from gicore.error_policy import UserError
from gicore.heldout_cases import Case, case_datasets, verdicts
from gicore.metrics import all_metrics, chroma_error, object_mask, object_psnr
from gicore.tonemap import tonemap
from gigan_local.inference import GIModel, model_info

#: The object scores' units (the whole frame's are bench quality's).
UNITS = {"object_psnr": "dB", "gain_db": "dB", "chroma_error": "1"}
FRAME_METRICS = ("ssim", "psnr", "rmse", "lf_error")


def case_scores(case: Case, root: Path, models: dict[str, GIModel], max_frames: int | None) -> dict[str, dict]:
    """Per system (``di_only`` and each model): the scores of ``case``, whose dataset is ``root``."""
    meta = read_meta(root)
    outputs: dict[str, list[np.ndarray]] = {name: [] for name in ("di_only", *models)}
    references, masks = [], []
    for path in frame_paths(root, "val")[:max_frames]:
        frame = load_frame(path, meta.buffers)
        references.append(tonemap(frame["gt"]))
        masks.append(object_mask(frame["albedo"], case.albedo))
        outputs["di_only"].append(tonemap(frame["di"]))
        for name, model in models.items():
            outputs[name].append(tonemap(model.predict(frame)))
    if not np.concatenate(masks).any():
        raise UserError(f"{root}: no frame shows the {case.shape}", f"delete {root} to render its frames again")
    reference, mask = np.concatenate(references), np.concatenate(masks)  # the frames stacked: pooled pixels
    scores = {}
    for name, images in outputs.items():
        image = np.concatenate(images)
        per_frame = [all_metrics(a, b) for a, b in zip(images, references)]
        scores[name] = {m: float(np.mean([f[m] for f in per_frame])) for m in FRAME_METRICS} | {
            "object_psnr": object_psnr(image, reference, mask),
            "chroma_error": chroma_error(image, reference, mask),
            "frames": len(images),
        }
    for s in scores.values():
        s["gain_db"] = s["object_psnr"] - scores["di_only"]["object_psnr"]
    return scores


def score_models(
    models: dict[str, Path], root: Path, max_frames: int | None = None, threads: int = 2
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The check of the exported ``models`` (system name -> ONNX file) on the cases rendered (where missing) under
    ``root`` at their resolution: (score rows: system, case, metric, value, frames; target rows: system, case,
    target, measured, met, for each model)."""
    resolutions = {model_info(path, f"--models {name}")["resolution"] for name, path in models.items()}
    if len(resolutions) != 1:
        raise UserError(
            f"--models run at {', '.join(f'{r}²' for r in sorted(resolutions))}",
            "check models of one resolution together (the cases render at it)",
        )
    loaded = {name: GIModel(path, threads=threads) for name, path in models.items()}
    per_system: dict[str, dict[str, dict]] = {name: {} for name in ("di_only", *models)}
    for case, folder in case_datasets(root, resolutions.pop()):
        for name, scores in case_scores(case, folder, loaded, max_frames).items():
            per_system[name][case.name] = scores
    rows = [
        {"system": name, "case": case, "metric": metric, "value": value, "frames": scores["frames"]}
        for name, by_case in per_system.items()
        for case, scores in by_case.items()
        for metric, value in scores.items()
        if metric != "frames"
    ]
    checks = [c | {"system": name} for name in models for c in verdicts(per_system[name])]
    return rows, checks
