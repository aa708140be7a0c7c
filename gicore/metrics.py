"""Image-quality metrics on tone-mapped images in [0, 1] (docs/architecture.md, Tone mapping and metrics).

Inputs outside [0, 1] (e.g. linear HDR radiance, where SSIM's ``data_range=1`` is meaningless) and
NaN/Inf are refused with a ValueError rather than scored: tone-map with ``gicore.tonemap`` first.

SSIM follows the Wang et al. settings that scikit-image reproduces: Gaussian window with sigma 1.5,
population covariance, ``data_range=1``. Identical images give PSNR = inf (not an error); constant
images give a defined SSIM thanks to the C1/C2 stabilisers.

The low-frequency error (:func:`lf_error`) is the mean absolute value of the Gaussian-blurred (sigma
:data:`LF_SIGMA` pixels) difference: it measures brightness errors that cover many pixels ("blotches"),
which SSIM barely sees and RMSE/PSNR mix with fine noise. The checkerboard error
(:func:`checker_error`) is the opposite end: the part of the error that repeats on a small pixel tile,
the signature of stride-2 transposed convolutions. The object metrics (:func:`object_mask`, :func:`object_psnr`,
:func:`chroma_error`) score one object's own pixels, which a frame-wide score dilutes with the floor's.
"""

from __future__ import annotations

import math

import numpy as np

#: Standard deviation, in pixels at the evaluated resolution, of the Gaussian that :func:`lf_error` blurs
#: the difference with (6 px at 256²: a few percent of the frame). At another resolution the same
#: number of pixels is a different fraction of the image: compare lf_error values only at one resolution.
LF_SIGMA = 6.0
#: How :func:`lf_difference` extends the image past its border (scipy.ndimage's 'reflect': the edge pixel
#: repeated, d c b a | a b c d), so a constant difference stays exactly constant up to the border.
LF_MODE = "reflect"
#: Tile side, in pixels, of :func:`checker_error`: 4 covers the period-2 and period-4 patterns that the
#: two outermost stride-2 up-sampling layers of a U-Net print on its output.
CHECKER_PERIOD = 4
#: :func:`shadow_tint`'s mask: pixels whose tone-mapped DI luminance is below SHADOW_DI (direct light does
#: not reach them) and whose GT luminance is above SHADOW_LIT (indirect light does).
SHADOW_DI, SHADOW_LIT = 0.05, 0.02
#: :func:`object_mask`'s tolerance per albedo channel: above the float16 storage's rounding (5e-4 near 1).
OBJECT_TOL = 0.01
#: :func:`chroma_error`'s lit pixels: tone-mapped GT channel mean above this (linear ~0.03); darker pixels' colour is
#: mostly the GT's path-tracing noise.
CHROMA_LIT = 0.2


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
            raise ValueError(
                f"the {name} image has values in [{img.min():.4g}, {img.max():.4g}], outside [0, 1]; tone-map "
                "it first (gicore.tonemap)"
            )
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
    # Imported here: scikit-image's filters bring scipy.ndimage (0.4 s), which the processes that import this
    # module for its cheap metrics (the server, the proxies' clients) never need.
    from skimage.metrics import structural_similarity

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
    from skimage.filters import gaussian  # imported here, as in ssim

    a, b = _check_pair(a, b)
    if not (math.isfinite(sigma) and sigma >= 0.0):
        raise ValueError(f"sigma must be a finite number of pixels >= 0, got {sigma}")
    return gaussian(
        a - b, sigma=sigma, mode=LF_MODE, truncate=4.0, preserve_range=True, channel_axis=-1 if a.ndim == 3 else None
    )


def lf_error(a: np.ndarray, b: np.ndarray, sigma: float = LF_SIGMA) -> float:
    """Low-frequency error: mean over pixels and channels of |Gaussian_sigma(a - b)| (:func:`lf_difference`).

    Why it exists: a brightness error that covers a region (a "blotch") moves SSIM very little,
    because SSIM's luminance term (2 mu_a mu_b + C1) / (mu_a^2 + mu_b^2 + C1) stays near 1 for a small
    offset (0.05 at mean 0.5: 0.995) and its structure term ignores offsets altogether; RMSE/PSNR do see it,
    but cannot tell it from fine noise. Here fine, zero-mean errors (noise, a checkerboard) average out under
    the blur while a constant offset ``c`` scores exactly ``|c|``. The blur (symmetric kernel, 'reflect'
    border) is a symmetric, doubly stochastic operator, so lf_error <= mean |a - b| <= RMSE: it is the part
    of the error that stays after local averaging. ``sigma`` is in pixels at the evaluated
    resolution (default :data:`LF_SIGMA`). Same inputs as the other metrics: tone-mapped, in [0, 1].
    """
    return float(np.mean(np.abs(lf_difference(a, b, sigma))))


def checker_error(a: np.ndarray, b: np.ndarray, period: int = CHECKER_PERIOD) -> float:
    """Checkerboard error: the mean absolute value of the part of ``a - b`` that repeats on a
    ``period`` x ``period`` tile, per channel.

    The difference is averaged over all tiles (the tile grid starts at pixel 0, 0; rows and columns past
    the last whole tile are left out), giving one ``period`` x ``period`` pattern per channel; its mean is
    subtracted (a constant offset is :func:`lf_error`'s business), and the mean |pattern| is returned. A
    ``±h`` checkerboard (or ``±h`` stripes of period 2 or 4) scores exactly ``h``, a constant offset 0;
    errors that do not repeat average out over the tiles: zero-mean noise of deviation s scores about
    ``s * period / sqrt(H * W)``, and a smooth ramp rising ``g`` per pixel scores at most ``g * period / 2``.
    """
    a, b = _check_pair(a, b)
    if not (isinstance(period, int) and period >= 2):
        raise ValueError(f"period must be an integer >= 2, got {period!r}")
    d = (a - b) if a.ndim == 3 else (a - b)[..., None]
    h, w = (d.shape[0] // period) * period, (d.shape[1] // period) * period
    if h == 0 or w == 0:
        raise ValueError(f"images of {d.shape[0]}x{d.shape[1]} pixels hold no {period}x{period} tile")
    tile = d[:h, :w].reshape(h // period, period, w // period, period, d.shape[2]).mean(axis=(0, 2))
    return float(np.mean(np.abs(tile - tile.mean(axis=(0, 1)))))


def shadow_tint(a: np.ndarray, b: np.ndarray, di: np.ndarray) -> float:
    """Red tint of ``a`` against ``b`` where only indirect light arrives: the mean, over the pixels that
    :data:`SHADOW_DI` / :data:`SHADOW_LIT` select from the tone-mapped ``di`` and ``b``, of the error's red
    channel minus the mean of its green and blue, (R - (G + B) / 2) of ``a - b``. Positive: redder than
    ``b``; 0 for a grey error (a brightness offset) or no such pixel (NaN would poison the means).
    """
    a, b = _check_pair(a, b)
    _, di = _check_pair(a, di)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"shadow_tint needs RGB images (HxWx3), got shape {a.shape}")
    mask = (di.mean(axis=2) < SHADOW_DI) & (b.mean(axis=2) > SHADOW_LIT)
    if not mask.any():
        return 0.0
    e = (a - b)[mask]
    return float(np.mean(e[:, 0] - 0.5 * (e[:, 1] + e[:, 2])))


def object_mask(albedo: np.ndarray, colour: tuple[float, float, float], tol: float = OBJECT_TOL) -> np.ndarray:
    """The pixels (HxW bool) whose G-buffer ``albedo`` (HxWx3) is the object's ``colour`` within ``tol`` per channel:
    an object's own pixels where no other surface shares its colour."""
    return np.all(np.abs(np.asarray(albedo, np.float64) - np.asarray(colour, np.float64)) <= tol, axis=-1)


def object_psnr(prediction: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """PSNR in dB over the pixels of ``mask`` (all channels) of tone-mapped images; NaN where the mask is empty."""
    a, b = _check_pair(prediction, reference)
    if not mask.any():
        return math.nan
    err = float(np.sqrt(np.mean((a[mask] - b[mask]) ** 2)))
    return math.inf if err == 0.0 else float(-20.0 * math.log10(err))


def chroma_error(prediction: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """Chroma error: the mean, over the pixels of ``mask`` that the (tone-mapped) ``reference`` lights (channel mean
    above :data:`CHROMA_LIT`), of the L1 distance between the chromaticities r,g,b / (r + g + b) of ``prediction``
    and ``reference``: 0 for the right colour at any brightness, up to 2 for pure red against pure green. NaN where
    no such pixel is lit."""
    a, b = _check_pair(prediction, reference)
    lit = mask & (b.mean(axis=-1) > CHROMA_LIT)
    if not lit.any():
        return math.nan
    pa, pb = a[lit], b[lit]
    ca = pa / np.maximum(pa.sum(axis=-1, keepdims=True), 1e-12)
    cb = pb / pb.sum(axis=-1, keepdims=True)
    return float(np.mean(np.abs(ca - cb).sum(axis=-1)))


def all_metrics(prediction: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """RMSE, PSNR, SSIM and the low-frequency error of ``prediction`` against ``reference`` (both tone-mapped,
    in [0, 1])."""
    return {
        "rmse": rmse(prediction, reference),
        "psnr": psnr(prediction, reference),
        "ssim": ssim(prediction, reference),
        "lf_error": lf_error(prediction, reference),
    }
