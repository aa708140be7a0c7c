"""Which backend runs GIGAN's generator: ``--inference auto|onnxruntime|torch``.

``auto`` is torch where torch sees a CUDA device (:func:`gicore.cuda_probe.cuda_for_torch`: float16
on the GPU, host copies counted in the inference stage) and onnxruntime on the CPU otherwise, the backend
the shipped model was tuned for on two cores. Either backend can be forced; torch without CUDA runs float32
on the CPU.
"""

from __future__ import annotations

from pathlib import Path

from gicore.error_policy import UserError
from gigan_local.inference import ExportedGenerator, GIModel

#: ``--inference`` choices.
INFERENCE_BACKENDS = ("auto", "onnxruntime", "torch")


def resolve_inference(asked: str, cuda: bool | None = None) -> str:
    """The backend ``--inference asked`` runs on: ``auto`` is torch where ``cuda`` (torch sees a CUDA device;
    asked of :func:`gicore.cuda_probe.cuda_for_torch` when None), else onnxruntime."""
    if asked not in INFERENCE_BACKENDS:
        raise UserError(f"--inference {asked!r} is not a backend", f"use one of {', '.join(INFERENCE_BACKENDS)}")
    if asked != "auto":
        return asked
    if cuda is None:
        from gicore.cuda_probe import cuda_for_torch

        cuda = cuda_for_torch()
    return "torch" if cuda else "onnxruntime"


def open_model(path: str | Path, inference: str = "auto", threads: int = 2, warmup: int = 2) -> ExportedGenerator:
    """The exported generator at ``path`` on the backend ``inference`` resolves to (:func:`resolve_inference`)."""
    if resolve_inference(inference) == "onnxruntime":
        return GIModel(path, threads, warmup)
    from gigan_local.torch_backend import TorchGIModel

    return TorchGIModel(path, threads, warmup)
