"""Whether this machine has a CUDA device, asked of the driver (libcuda) directly.

Both Mitsuba's variant choice (:mod:`gicore.mitsuba_variant`) and GIGAN's inference backend
(:mod:`gigan_local.backend_choice`) need to know before they import a CUDA library: Mitsuba's variant is set
once per process, and importing torch only to learn that there is no GPU costs about 2 s. A machine without
the NVIDIA driver has no ``libcuda.so.1``, so the answer there costs one failed ``dlopen``.
"""

from __future__ import annotations

import ctypes
import functools
import importlib.util


@functools.cache
def cuda_device_count() -> int:
    """The number of CUDA devices the driver reports: 0 without a driver, without a device, or when the
    driver fails to initialise (``cuInit``)."""
    try:
        cuda = ctypes.CDLL("libcuda.so.1")
    except OSError:
        return 0
    count = ctypes.c_int(0)
    if cuda.cuInit(0) != 0 or cuda.cuDeviceGetCount(ctypes.byref(count)) != 0:
        return 0
    return count.value


def cuda_for_torch() -> bool:
    """Whether torch runs on a CUDA device here (the project's CPU wheel never does). The driver is asked first
    (:func:`cuda_device_count`), so a machine without a GPU does not import torch (about 2 s) to find out."""
    if cuda_device_count() == 0 or importlib.util.find_spec("torch") is None:
        return False
    import torch

    return torch.cuda.is_available()
