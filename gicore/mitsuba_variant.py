"""Which Mitsuba variant and GT denoiser a process uses, decided before :mod:`gicore.render` imports Mitsuba.

``GIGAN_MITSUBA_VARIANT`` (the environment, so that every process a command or bench starts inherits it)
takes ``auto`` (the default), ``cpu`` or ``cuda``:

- ``cuda``: ``cuda_ad_rgb``, which needs a CUDA device (:func:`gicore.cuda_probe.cuda_device_count`) and a
  Mitsuba build with that variant; the GT is denoised by Mitsuba's own OptiX denoiser (part of the
  driver, no wheel to install), or, where the driver lacks that denoiser's weights file (some container
  images mount the driver's libraries without it), by OIDN on the same CUDA device (``pyoidn``, through torch);
- ``cpu``: ``llvm_ad_rgb``, which needs libLLVM >= 16 (older ones abort the process inside Dr.Jit, so the
  library is located before the import), else the ~45x slower ``scalar_rgb``; the GT is denoised by Intel
  Open Image Denoise (``pyoidn``);
- ``auto``: ``cuda`` where it can run, else ``cpu``.

:func:`choose_variant` is the decision, a pure function of what was asked and what the machine has;
:func:`mitsuba_choice` makes it once per process from the environment and prints its one-line notice on
stderr (not in a worker process a pool spawned: its parent printed it). Asking for ``cuda`` where it cannot
run is a one-line user error.
"""

from __future__ import annotations

import functools
import glob
import importlib.util
import multiprocessing
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from gicore.cuda_probe import cuda_device_count, cuda_for_torch
from gicore.error_policy import UserError

#: The environment variable that picks the device, and its values.
VARIANT_ENV = "GIGAN_MITSUBA_VARIANT"
DEVICES = ("auto", "cpu", "cuda")
CUDA_VARIANT, LLVM_VARIANT, SCALAR_VARIANT = "cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb"


@dataclass(frozen=True)
class VariantChoice:
    """A process's Mitsuba variant, the denoiser of its GT renders, and the line that says why."""

    variant: str
    #: "optix" (Mitsuba's, on the CUDA variant), "oidn-cuda" (pyoidn on the CUDA device, on the CUDA variant
    #: where the driver has no OptiX denoiser weights) or "oidn" (pyoidn on the CPU, on the CPU variants).
    denoiser: str
    notice: str

    @property
    def needs_pyoidn(self) -> bool:
        return self.denoiser.startswith("oidn")


#: Where the driver's OptiX library reads its denoiser's weights; without the file the denoiser cannot start.
OPTIX_DENOISER_WEIGHTS = Path("/usr/share/nvidia/nvoptix.bin")


def choose_variant(
    asked: str,
    cuda_devices: int,
    cuda_variant_built: bool,
    libllvm: str | None,
    optix_weights: bool = True,
    torch_cuda: bool = True,
) -> VariantChoice:
    """The variant for ``GIGAN_MITSUBA_VARIANT=asked`` on a machine with ``cuda_devices`` CUDA devices, a Mitsuba
    build that has (``cuda_variant_built``) or lacks the CUDA variant, ``libllvm`` (a path, or None), a driver
    that has (``optix_weights``) or lacks the OptiX denoiser's weights, and a torch that can (``torch_cuda``) or
    cannot hand OIDN CUDA tensors (the project's CPU wheel cannot: OIDN then denoises on the CPU)."""
    if asked not in DEVICES:
        raise UserError(f"{VARIANT_ENV}={asked!r} is not a device", f"set it to one of {', '.join(DEVICES)}")
    cuda_runs = cuda_devices > 0 and cuda_variant_built
    if asked == "cuda" and not cuda_runs:
        missing = "no CUDA device" if cuda_devices == 0 else f"this Mitsuba build has no {CUDA_VARIANT}"
        raise UserError(f"{VARIANT_ENV}=cuda but {missing}", f"set {VARIANT_ENV}=cpu or auto, or leave it unset")
    if asked != "cpu" and cuda_runs:
        if not optix_weights:
            where = "the GPU" if torch_cuda else "the CPU (torch has no CUDA)"
            notice = (
                f"mitsuba: {CUDA_VARIANT} on the GPU, OIDN denoiser on {where}: the driver has no OptiX denoiser "
                f"weights ({OPTIX_DENOISER_WEIGHTS}) ({why(asked)})"
            )
            return VariantChoice(CUDA_VARIANT, "oidn-cuda" if torch_cuda else "oidn", notice)
        notice = f"mitsuba: {CUDA_VARIANT} on the GPU, OptiX denoiser ({why(asked)})"
        return VariantChoice(CUDA_VARIANT, "optix", notice)
    reason = why(asked) if asked == "cpu" else "no CUDA device" if cuda_devices == 0 else f"no {CUDA_VARIANT} built"
    if libllvm is None:
        return VariantChoice(
            SCALAR_VARIANT,
            "oidn",
            f"mitsuba: {SCALAR_VARIANT}, about 45x slower than {LLVM_VARIANT}, which needs libLLVM >= 16 "
            f"({reason}; apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH)",
        )
    return VariantChoice(LLVM_VARIANT, "oidn", f"mitsuba: {LLVM_VARIANT} on the CPU, OIDN denoiser ({reason})")


def why(asked: str) -> str:
    """How the choice was made, for the notice."""
    return f"{VARIANT_ENV}={asked}" if asked != "auto" else f"auto; {VARIANT_ENV}=cpu|cuda forces one"


def find_libllvm() -> str | None:
    """Path of a libLLVM >= 16 shared library (``DRJIT_LIBLLVM_PATH`` when set), or None."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    for pattern in ("/usr/lib/*/libLLVM-{v}.so*", "/usr/lib/*/libLLVM.so.{v}*", "/usr/lib/llvm-{v}/lib/libLLVM*.so*"):
        for version in range(22, 15, -1):
            hits = sorted(glob.glob(pattern.format(v=version)))
            if hits:
                return hits[0]
    return None


def cuda_variant_built() -> bool:
    """Whether the installed Mitsuba has the CUDA variant's extension (found on disk: importing Mitsuba to
    ask would load Dr.Jit before its LLVM is located)."""
    spec = importlib.util.find_spec("mitsuba")
    folders = spec.submodule_search_locations if spec else None
    return any(glob.glob(str(Path(folder) / f"{CUDA_VARIANT}.*")) for folder in folders or [])


def machine_choice(asked: str) -> VariantChoice:
    """:func:`choose_variant` for ``asked`` on this machine; the CUDA probe runs only where CUDA could be asked for."""
    cuda_devices = cuda_device_count() if asked in ("auto", "cuda") else 0
    optix = OPTIX_DENOISER_WEIGHTS.is_file()
    # torch (seconds to import) is asked only where OIDN would denoise next to the CUDA variant
    torch_cuda = optix or cuda_devices == 0 or cuda_for_torch()
    return choose_variant(asked, cuda_devices, cuda_variant_built(), find_libllvm(), optix, torch_cuda)


@functools.cache
def mitsuba_choice() -> VariantChoice:
    """This process's choice (:func:`machine_choice` of ``GIGAN_MITSUBA_VARIANT``), its notice printed once on
    stderr."""
    choice = machine_choice(os.environ.get(VARIANT_ENV, "auto").strip().lower() or "auto")
    if multiprocessing.parent_process() is None:
        print(choice.notice, file=sys.stderr, flush=True)
    return choice


def check_denoiser(denoise: bool) -> None:
    """Denoising the path-traced GT needs pyoidn unless OptiX denoises (on the CUDA variant, where the driver has
    its weights): say so before any frame is rendered."""
    if denoise and mitsuba_choice().needs_pyoidn and importlib.util.find_spec("pyoidn") is None:
        raise UserError("denoising the GT renders needs pyoidn", "pip install pyoidn, or turn it off with --no-denoise")
