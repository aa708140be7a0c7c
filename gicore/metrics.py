"""Image-quality metrics on tone-mapped images in [0, 1] (SPEC §3).

Inputs outside [0, 1] (e.g. linear HDR radiance, where SSIM's ``data_range=1`` is meaningless) and
NaN/Inf are refused with a ValueError rather than scored (SPEC §9): tone-map with ``gicore.tonemap`` first.

SSIM follows the Wang et al. settings that scikit-image reproduces: Gaussian window with sigma 1.5,
population covariance, ``data_range=1``. Identical images give PSNR = inf (not an error); constant
images give a defined SSIM thanks to the C1/C2 stabilisers.

The low-frequency error (:func:`lf_error`) is the mean absolute value of the Gaussian-blurred (sigma
:data:`LF_SIGMA` pixels) difference: it measures brightness errors that cover many pixels ("blotches"),
which SSIM barely sees and RMSE/PSNR mix with fine noise.
"""

from __future__ import annotations

import math

import numpy as np
from skimage.filters import gaussian
from skimage.metrics import structural_similarity

#: Standard deviation, in pixels at the evaluated resolution, of the Gaussian that :func:`lf_error` blurs
#: the difference with (issue 14: 6 px at 256², a few percent of the frame). At another resolution the same
#: number of pixels is a different fraction of the image: compare lf_error values only at one resolution.
LF_SIGMA = 6.0
#: How :func:`lf_difference` extends the image past its border (scipy.ndimage's 'reflect': the edge pixel
#: repeated, d c b a | a b c d), so a constant difference stays exactly constant up to the border.
LF_MODE = "reflect"


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


def lf_difference(a: np.ndarray, b: np.ndarray, sigma: float = LF_SIGMA) -> np.ndarray:
    """The signed difference ``a - b`` blurred by a Gaussian of ``sigma`` pixels, each channel on its own
    (no blur across channels), border mode :data:`LF_MODE`, kernel truncated at 4 sigma; same shape as the
    inputs. The map behind :func:`lf_error` (and ``bench quality``'s error images)."""
    a, b = _check_pair(a, b)
    if not (math.isfinite(sigma) and sigma >= 0.0):
        raise ValueError(f"sigma must be a finite number of pixels >= 0, got {sigma}")
    return gaussian(a - b, sigma=sigma, mode=LF_MODE, truncate=4.0, preserve_range=True, channel_axis=-1 if a.ndim == 3 else None)


def lf_error(a: np.ndarray, b: np.ndarray, sigma: float = LF_SIGMA) -> float:
    """Low-frequency error: mean over pixels and channels of |Gaussian_sigma(a - b)| (:func:`lf_difference`).

    Why it exists (issue 14): a brightness error that covers a region (a "blotch") moves SSIM very little,
    because SSIM's luminance term (2 mu_a mu_b + C1) / (mu_a^2 + mu_b^2 + C1) stays near 1 for a small
    offset (0.05 at mean 0.5: 0.995) and its structure term ignores offsets altogether; RMSE/PSNR do see it,
    but cannot tell it from fine noise. Here fine, zero-mean errors (noise, a checkerboard) average out under
    the blur while a constant offset ``c`` scores exactly ``|c|``. The blur (symmetric kernel, 'reflect'
    border) is a symmetric, doubly stochastic operator, so lf_error <= mean |a - b| <= RMSE: it is the part
    of the error that stays after local averaging. ``sigma`` is in pixels at the evaluated
    resolution (default :data:`LF_SIGMA`). Same inputs as the other metrics: tone-mapped, in [0, 1].
    """
    return float(np.mean(np.abs(lf_difference(a, b, sigma))))


def all_metrics(prediction: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """RMSE, PSNR, SSIM and the low-frequency error of ``prediction`` against ``reference`` (both tone-mapped, [0, 1])."""
    return {
        "rmse": rmse(prediction, reference),
        "psnr": psnr(prediction, reference),
        "ssim": ssim(prediction, reference),
        "lf_error": lf_error(prediction, reference),
    }
