"""The exported models a bench runs (``gigan-export`` folders): what ``model.json`` says about each, read
before anything is measured so that a missing or mismatched model fails at once, naming the option."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from gicore.error_policy import UserError


def model_info(path: Path, option: str) -> dict[str, Any]:
    """Architecture, precision, resolution and size of the model file ``path`` given by ``option``."""
    if not path.is_file():
        raise UserError(f"{option} {path}: no such model file", "give an .onnx file written by gigan-export")
    doc_path = path.parent / "model.json"
    try:
        doc = json.loads(doc_path.read_text())
        precision = next((k for k, v in doc["files"].items() if v == path.name), "unknown")
        return {
            "ngf": doc["ngf"],
            "precision": precision,
            "model": doc["model"],
            "resolution": doc["resolution"],
            "size_mib": round(path.stat().st_size / 2**20, 2),
        }
    except (OSError, ValueError, KeyError, AttributeError) as exc:
        raise UserError(
            f"{option} {path}: {doc_path} is missing or not a gigan-export model.json ({exc})",
            "keep the model.json that gigan-export wrote beside the model",
        ) from None


def check_model_resolution(path: Path, resolution: int, option: str = "--model") -> None:
    """The model must run at the bench's ``--resolution`` (a U-Net is built for one frame size)."""
    expected = model_info(path, option)["resolution"]
    if expected != resolution:
        raise UserError(
            f"{option} {path} runs at {expected}² but --resolution is {resolution}", f"pass --resolution {expected}"
        )
