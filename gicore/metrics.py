"""Image-quality metrics on tone-mapped images in [0, 1] (SPEC §3).

Inputs outside [0, 1] (e.g. linear HDR radiance, where SSIM's ``data_range=1`` is meaningless) and
NaN/Inf are refused with a ValueError rather than scored (SPEC §9): tone-map with ``gicore.tonemap`` first.

SSIM follows the Wang et al. settings that scikit-image reproduces: Gaussian window with sigma 1.5,
population covariance, ``data_range=1``. Identical images give PSNR = inf (not an error); constant
images give a defined SSIM thanks to the C1/C2 stabilisers.
"""

from __future__ import annotations

import math

import numpy as np
from skimage.metrics import structural_similarity


def _check_pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.ndim not in (2, 3):
        raise ValueError(f"expected an HxW or HxWxC image, got shape {a.shape}")
    for name, img in (("first", a), ("second", b)):
        if not np.all(np.isfinite(img)):
            raise ValueError(f"the {name} image contains NaN or Inf; tone-map finite radiance first")
        if img.size and (img.min() < 0.0 or img.max() > 1.0):
            raise ValueError(f"the {name} image has values in [{img.min():.4g}, {img.max():.4g}], outside [0, 1]; tone-map it first (gicore.tonemap)")
    return a, b


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean squared error over all pixels and channels."""
    a, b = _check_pair(a, b)
    return float(np.sqrt(np.mean((a - b) ** 2)))


def psnr(a: np.ndarray, b: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB; ``inf`` for identical images."""
    err = rmse(a, b)
    return math.inf if err == 0.0 else float(20.0 * math.log10(data_range / err))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM (Gaussian sigma 1.5, population covariance, data range 1), per channel averaged."""
    a, b = _check_pair(a, b)
    return float(
        structural_similarity(
            a,
            b,
            data_range=1.0,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
            channel_axis=-1 if a.ndim == 3 else None,
        )
    )


def all_metrics(prediction: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """RMSE, PSNR and SSIM of ``prediction`` against ``reference`` (both tone-mapped, [0, 1])."""
    return {"rmse": rmse(prediction, reference), "psnr": psnr(prediction, reference), "ssim": ssim(prediction, reference)}
