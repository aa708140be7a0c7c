"""Metrics, the tone map and DI/GI composition against hand-computed cases and edge inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gicore.blend import blend, residual
from gicore.fill import push_pull
from gicore.metrics import LF_SIGMA, all_metrics, lf_difference, lf_error, psnr, rmse, ssim
from gicore.tonemap import GAMMA, Y_MAX, from_signed, inverse_tonemap, to_signed, tonemap

RNG = np.random.default_rng(1234)


def image(h=32, w=32, c=3):
    return RNG.uniform(0.0, 1.0, size=(h, w, c))


# -- metrics ---------------------------------------------------------------------------------------------
def test_hand_computed_rmse_psnr():
    a = np.zeros((16, 16, 3))
    b = np.full((16, 16, 3), 0.1)
    assert rmse(a, b) == pytest.approx(0.1)
    assert psnr(a, b) == pytest.approx(20.0)
    assert psnr(a, np.full_like(a, 0.01)) == pytest.approx(40.0)
    assert psnr(a, b, data_range=10.0) == pytest.approx(40.0)
    # Half the pixels off by 0.2: RMSE = sqrt(0.5 * 0.04).
    c = a.copy()
    c[:8] = 0.2
    assert rmse(a, c) == pytest.approx(math.sqrt(0.02))
    assert rmse(a, b) == rmse(b, a)


def test_identical_images():
    a = image()
    m = all_metrics(a, a.copy())
    assert m["rmse"] == 0.0
    assert m["psnr"] == math.inf
    assert m["ssim"] == pytest.approx(1.0)
    assert m["lf_error"] == 0.0
    gray = a[..., 0]
    assert psnr(gray, gray) == math.inf and ssim(gray, gray) == pytest.approx(1.0) and lf_error(gray, gray) == 0.0


@pytest.mark.parametrize("ca,cb", [(0.0, 0.0), (0.5, 0.5), (1.0, 1.0), (0.2, 0.5), (0.0, 1.0)])
def test_constant_images_have_defined_ssim(ca, cb):
    a = np.full((24, 24, 3), ca)
    b = np.full((24, 24, 3), cb)
    s = ssim(a, b)
    assert np.isfinite(s)
    # Zero variance: SSIM reduces to the luminance term (2 mu_a mu_b + C1) / (mu_a^2 + mu_b^2 + C1).
    c1 = (0.01 * 1.0) ** 2
    expected = (2 * ca * cb + c1) / (ca**2 + cb**2 + c1)
    assert s == pytest.approx(expected, abs=1e-6)


def test_ssim_hand_computed_contrast_case():
    a = image()
    noisy = np.clip(a + RNG.normal(0, 0.05, a.shape), 0, 1)
    very_noisy = np.clip(a + RNG.normal(0, 0.3, a.shape), 0, 1)
    assert 1.0 > ssim(a, noisy) > ssim(a, very_noisy) > -1.0
    assert psnr(a, noisy) > psnr(a, very_noisy)
    assert ssim(a, noisy) == pytest.approx(ssim(noisy, a))


def test_ssim_uses_the_paper_settings():
    from skimage.metrics import structural_similarity

    a, b = image(), image()
    ref = structural_similarity(
        a, b, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, channel_axis=-1
    )
    assert ssim(a, b) == pytest.approx(ref)
    # Channels are averaged: a per-channel mean equals the multichannel value.
    per = [ssim(a[..., i], b[..., i]) for i in range(3)]
    assert ssim(a, b) == pytest.approx(np.mean(per))


@pytest.mark.parametrize("fn", [rmse, psnr, ssim, lf_error, lf_difference, all_metrics])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", [0, 1])
def test_nan_inf_input_rejected(fn, bad, which):
    imgs = [image(), image()]
    imgs[which][3, 4, 1] = bad
    with pytest.raises(ValueError, match="NaN or Inf"):
        fn(*imgs)


@pytest.mark.parametrize("fn", [rmse, psnr, ssim, lf_error, lf_difference, all_metrics])
@pytest.mark.parametrize("value", [-0.01, 1.01, 40.0])
def test_values_outside_unit_range_rejected(fn, value):
    """Linear HDR radiance (or any value outside [0, 1]) is not scored as if it were display values."""
    imgs = [image(), image()]
    imgs[1][5, 6, 0] = value
    with pytest.raises(ValueError, match=r"second image has values in \[.*\], outside \[0, 1\]; tone-map it first"):
        fn(*imgs)


def test_unit_range_endpoints_are_accepted():
    zeros, ones = np.zeros((8, 8, 3)), np.ones((8, 8, 3))
    assert rmse(zeros, ones) == 1.0


@pytest.mark.parametrize("fn", [inverse_tonemap, from_signed])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_inverse_tone_map_and_from_signed_reject_non_finite(fn, bad):
    """np.clip keeps NaN, so without the check it would pass straight through into the GI maps."""
    with pytest.raises(ValueError, match=f"{fn.__name__} input contains NaN or Inf"):
        fn(np.array([0.2, bad, 0.7], dtype=np.float32))


@pytest.mark.parametrize("which", ["image", "weight"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_push_pull_rejects_non_finite(which, bad):
    """Even a NaN in a zero-weight pixel would spread through the pyramid into every hole."""
    img, wgt = np.ones((8, 8, 3), np.float32), np.ones((8, 8), np.float32)
    wgt[2:5, 2:5] = 0.0
    (img if which == "image" else wgt)[3, 3] = bad
    with pytest.raises(ValueError, match=f"push_pull {which} contains NaN or Inf"):
        push_pull(img, wgt)


def test_push_pull_fills_holes_from_neighbours():
    img = np.zeros((8, 8, 3), np.float32)
    img[..., 0] = 2.0
    wgt = np.ones((8, 8), np.float32)
    wgt[2:5, 2:5] = 0.0
    img[2:5, 2:5] = 7.0  # values under zero weight are ignored
    out = push_pull(img, wgt)
    np.testing.assert_allclose(out[..., 0], 2.0, rtol=1e-6)
    np.testing.assert_allclose(out[..., 1:], 0.0, atol=1e-6)


def test_shape_mismatch_rejected():
    with pytest.raises(ValueError, match="shape"):
        rmse(image(16, 16), image(16, 17))
    with pytest.raises(ValueError, match="HxW"):
        ssim(np.zeros(10), np.zeros(10))


def test_black_vs_black_and_black_vs_white():
    black = np.zeros((16, 16, 3))
    white = np.ones((16, 16, 3))
    assert all_metrics(black, black) == {"rmse": 0.0, "psnr": math.inf, "ssim": pytest.approx(1.0), "lf_error": 0.0}
    m = all_metrics(black, white)
    assert (
        m["rmse"] == pytest.approx(1.0)
        and m["psnr"] == pytest.approx(0.0)
        and m["lf_error"] == pytest.approx(1.0, abs=1e-12)
    )
    assert m["ssim"] == pytest.approx(1e-4 / (1.0 + 1e-4), abs=1e-6)


# -- low-frequency error ------------------------------------------------------------------------------------
@pytest.mark.parametrize("c", [0.05, -0.05, 0.2])
@pytest.mark.parametrize("shape", [(64, 64, 3), (40, 72), (7, 9, 3)])
def test_lf_error_of_a_constant_offset_is_the_offset(c, shape):
    """The kernel sums to 1 and 'reflect' keeps a constant field constant to the border: |c| exactly."""
    a = RNG.uniform(0.3, 0.7, size=shape)
    assert lf_error(a + c, a) == pytest.approx(abs(c), abs=1e-6)
    np.testing.assert_allclose(lf_difference(a + c, a), c, atol=1e-6)  # signed: prediction minus reference
    assert lf_error(a, a + c) == pytest.approx(abs(c), abs=1e-6)


def test_lf_error_averages_out_a_checkerboard():
    """A zero-mean +-h checkerboard difference (mean |diff| = h) on N x N. The blur is separable, so the
    blurred map is h * B(i) * B(j) with B the 1-D blur of (-1)^k, and mean |.| = h * mean|B|^2. Inside, B
    is the kernel's alternating sum (about 2 exp(-pi^2 sigma^2 / 2), 0 in float64). Near an edge, 'reflect'
    repeats the edge pixel, flipping the pattern's phase beyond it; the error that adds at distance n is
    twice an alternating tail of the decreasing kernel, at most 2 g(n + 1), and summed over n at most
    2 * sum_{j>=1} g(j) < 1 per edge. So mean|B| <= 2 / N and lf_error <= h (2 / N)^2 = h / 1024 at N = 64."""
    n, h = 64, 0.1
    i, j = np.indices((n, n))
    diff = h * (-1.0) ** (i + j)
    a = RNG.uniform(0.2, 0.8, size=(n, n, 3))
    b = a + diff[..., None]
    assert np.mean(np.abs(b - a)) == pytest.approx(h)
    assert lf_error(b, a) <= h * (2 / n) ** 2
    assert lf_error(b, a) < 0.01 * rmse(b, a)  # RMSE counts all of it


def test_lf_error_blurs_each_channel_alone_and_sigma_zero_is_mean_abs_difference():
    a = RNG.uniform(0.2, 0.8, size=(32, 32, 3))
    b = a.copy()
    b[..., 0] += 0.1  # red only
    blurred = lf_difference(b, a)
    np.testing.assert_allclose(blurred[..., 0], 0.1, atol=1e-12)
    np.testing.assert_allclose(blurred[..., 1:], 0.0, atol=1e-12)  # nothing leaks into green and blue
    assert lf_error(b, a) == pytest.approx(0.1 / 3)
    noisy = np.clip(a + RNG.normal(0.0, 0.05, a.shape), 0.0, 1.0)
    assert lf_error(noisy, a, sigma=0.0) == pytest.approx(np.mean(np.abs(noisy - a)), rel=1e-12)
    assert lf_error(noisy, a) < lf_error(noisy, a, sigma=1.0) < lf_error(noisy, a, sigma=0.0)
    assert LF_SIGMA == 6.0
    with pytest.raises(ValueError, match="sigma"):
        lf_error(a, b, sigma=-1.0)


def test_lf_error_sees_a_brightness_offset_that_ssim_barely_moves():
    """On a real photograph (scikit-image's astronaut, bundled, squeezed into [0.05, 0.9] so +0.05 does not
    clip), at 256², a +0.05 brightness offset: lf_error 0.05, SSIM still 0.966 (measured; only SSIM's
    luminance term moves, (2 mu (mu + c) + C1) / (mu^2 + (mu + c)^2 + C1), >= 0.99 where the local mean
    mu >= 0.35, lower only in dark regions). Noise of the same RMSE is the other way round: SSIM 0.649,
    lf_error 0.0022. (The checkerboard bound above is met with room: 2.4e-5 against 9.8e-5.)"""
    from skimage import data

    ref = 0.05 + 0.85 * data.astronaut()[::2, ::2] / 255.0
    brighter = ref + 0.05
    noisy = np.clip(ref + np.random.default_rng(0).normal(0.0, 0.05, ref.shape), 0.0, 1.0)
    assert rmse(brighter, ref) == pytest.approx(0.05) and rmse(noisy, ref) == pytest.approx(0.05, rel=0.05)
    assert lf_error(brighter, ref) == pytest.approx(0.05, abs=1e-6)
    assert ssim(brighter, ref) > 0.95
    assert ssim(noisy, ref) < 0.7 and lf_error(noisy, ref) < 0.005
    assert lf_error(brighter, ref) > 10 * lf_error(noisy, ref)


# -- tone map --------------------------------------------------------------------------------------------
def test_tonemap_roundtrip_wide_range():
    x = np.logspace(-4, 3, 2000).astype(np.float32)
    back = inverse_tonemap(tonemap(x))
    np.testing.assert_allclose(back, x, rtol=1e-3)
    y = np.linspace(0.0, 0.999, 1001, dtype=np.float32)
    np.testing.assert_allclose(tonemap(inverse_tonemap(y)), y, atol=1e-5)


def test_tonemap_is_monotone_and_bounded():
    x = np.concatenate([[0.0], np.logspace(-6, 5, 5000)]).astype(np.float32)
    y = tonemap(x)
    assert np.all(np.diff(y) >= 0)
    coarse = tonemap(np.logspace(-4, 3, 200).astype(np.float32))
    assert np.all(np.diff(coarse) > 0)  # strictly increasing where float32 resolves it
    assert y[0] == 0.0 and np.all((y >= 0) & (y < 1))
    assert np.all(np.isfinite(y))
    yi = np.linspace(0, 1, 500, dtype=np.float32)
    assert np.all(np.diff(inverse_tonemap(yi)) >= 0)


def test_tonemap_hand_values_and_clipping():
    assert float(tonemap(np.float32(1.0))) == pytest.approx(0.5 ** (1 / GAMMA))
    assert float(tonemap(np.float32(-3.0))) == 0.0  # negatives clip to black
    assert float(inverse_tonemap(np.float32(0.0))) == 0.0
    top = float(inverse_tonemap(np.float32(1.0)))  # clipped at Y_MAX: large but finite
    assert np.isfinite(top) and top > 1e3
    assert top == pytest.approx(float(inverse_tonemap(np.float32(Y_MAX))))
    assert np.isfinite(float(inverse_tonemap(np.float32(2.0))))
    assert float(tonemap(np.float32(1e30))) <= 1.0


def test_tonemap_non_finite_input():
    # NaN/Inf inputs are rejected with a clear error. +inf radiance must not silently become
    # NaN (x / (1 + x) = inf / inf): either reject it or map it to the top of the range.
    try:
        top = tonemap(np.array([np.inf], dtype=np.float32))
    except ValueError:
        pass
    else:
        assert np.all(np.isfinite(top)) and top[0] == pytest.approx(1.0), top
    with pytest.raises(ValueError, match="NaN"):
        tonemap(np.array([0.5, np.nan], dtype=np.float32))


def test_signed_conversions():
    y = np.linspace(0, 1, 11)
    np.testing.assert_allclose(from_signed(to_signed(y)), y)
    assert to_signed(np.array(0.0)) == -1.0 and to_signed(np.array(1.0)) == 1.0
    np.testing.assert_array_equal(from_signed(np.array([-5.0, 5.0])), [0.0, 1.0])


# -- blending (eq. 1) and residual composition ----------------------------------------------------------------
def test_blend_endpoints_and_midpoint():
    di, gi = image() * 4, image() * 4
    np.testing.assert_allclose(blend(di, gi, 1.0), di, rtol=1e-6)
    np.testing.assert_allclose(blend(di, gi, 0.0), gi, rtol=1e-6)
    np.testing.assert_allclose(blend(di, gi, 0.25), 0.25 * di + 0.75 * gi, rtol=1e-6)


@pytest.mark.parametrize("tau", [-0.01, 1.01, 2.0, float("nan"), float("inf")])
def test_blend_tau_outside_unit_interval(tau):
    with pytest.raises(ValueError, match="tau"):
        blend(image(), image(), tau)


def test_blend_rejects_bad_inputs():
    bad = image()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="gi"):
        blend(image(), bad, 0.5)
    with pytest.raises(ValueError, match="shape"):
        blend(image(8, 8), image(8, 9), 0.5)


def test_residual_keeps_di_exact():
    di = (image() * 3).astype(np.float32)
    gi = (image() * 3).astype(np.float32)
    np.testing.assert_array_equal(residual(di, gi, gi.copy()), di)
    # Indirect light is added, never subtracted.
    di_of_gi = (gi * 0.5).astype(np.float32)
    out = residual(di, gi, di_of_gi)
    np.testing.assert_allclose(out, di + (gi - di_of_gi), rtol=1e-6)
    assert np.all(residual(di, di_of_gi, gi) == di)  # negative "indirect" clamps to 0


def test_residual_rejects_bad_inputs():
    bad = image()
    bad[1, 1, 1] = np.inf
    with pytest.raises(ValueError, match="di_of_gi"):
        residual(image(), image(), bad)
    with pytest.raises(ValueError, match="shapes"):
        residual(image(8, 8), image(8, 8), image(8, 9))
