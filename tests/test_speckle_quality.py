"""measurement.speckle_quality against independent references.

The references are never the module's own output: the analytic autocorrelation size of Gaussian-blob speckle
(scenes.image_pairs.gaussian_speckle.speckle_size_for_radius), the noise model the images were made with
(scenes.sensor.noise.noise_sigma_grey), counts and moments taken by hand with numpy, closed-form sums of squared
gradients of sinusoids and of the analytic speckle's exact gradient, and the scatter of the instrument's own
first-order DIC (measurement.dic.correlate) on a static pair.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from measurement.dic import DICSettings, correlate
from measurement.speckle_quality import (
    grey_statistics,
    noise_from_static_pair,
    pan_bound_px,
    region_mask,
    speckle_size_px,
    subset_advice,
    subset_sssig,
)
from scenes.sensor.noise import apply_sensor_noise, noise_sigma_grey
from scenes.image_pairs.fourier_shift import band_limit, fourier_shift
from scenes.image_pairs.gaussian_speckle import (extent_for_shape, gaussian_speckle, radius_for_speckle_size,
                                                 speckle_size_for_radius)


def speckle(shape, size_px, seed, *, periodic=False, mean_grey=128.0, std_grey=30.0):
    """Analytic Gaussian-blob speckle sampled at the pixel centres, and the blob pattern itself."""
    pattern = gaussian_speckle(extent_for_shape(shape), radius_for_speckle_size(size_px), 0.5, seed,
                               mean_grey=mean_grey, std_grey=std_grey, periodic=periodic)
    return pattern.render_reference(shape), pattern


def grid_points(shape, margin, step):
    y, x = np.mgrid[margin:shape[0] - margin:step, margin:shape[1] - margin:step]
    return x.ravel(), y.ravel()


# ------------------------------------------------------------------------------------------------------------
# Speckle size
# ------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("size_px", [3.0, 5.0, 8.0])
def test_speckle_size_matches_analytic_gaussian_speckle_within_10_percent(size_px):
    """The autocovariance FWHM of Gaussian blobs is known in closed form (speckle_size_for_radius); the
    measured size on 192 x 192 px must be within 10 % of it, over three patterns."""
    expected = speckle_size_for_radius(radius_for_speckle_size(size_px))
    assert expected == pytest.approx(size_px, rel=1e-6)        # the reference itself
    for seed in (1, 2, 3):
        image, _ = speckle((192, 192), size_px, seed)
        assert speckle_size_px(image) == pytest.approx(expected, rel=0.10)


@pytest.mark.parametrize("size_px", [3.0, 5.0, 8.0])
def test_speckle_size_ignores_a_smooth_shading_ramp_within_10_percent(size_px):
    """+40 grey of linear shading across the image (tiles remove their own mean) changes the size by < 10 %."""
    image, _ = speckle((192, 192), size_px, 4)
    x = np.arange(192)[None, :]
    shaded = image + 40.0 * x / 191.0
    assert speckle_size_px(shaded) == pytest.approx(speckle_size_px(image), rel=0.10)
    assert speckle_size_px(shaded) == pytest.approx(size_px, rel=0.10)


def test_speckle_size_of_a_masked_region_ignores_what_lies_outside_within_10_percent():
    """Left 192 columns: 5 px speckle; the right 96: coarse 30 px blobs of twice the contrast. The mask
    of the left half gives the left pattern's size within 10 %; the whole image does not."""
    rows, cols = 192, 288
    fine, _ = speckle((rows, cols), 5.0, 8)
    coarse, _ = speckle((rows, cols), 30.0, 9, std_grey=60.0)
    image = np.where(np.arange(cols)[None, :] < 192, fine, coarse)
    mask = np.zeros((rows, cols), dtype=bool)
    mask[:, :192] = True
    expected = speckle_size_for_radius(radius_for_speckle_size(5.0))
    assert speckle_size_px(image, mask) == pytest.approx(expected, rel=0.10)
    assert speckle_size_px(image) > 1.10 * expected      # the mask does something


def test_speckle_size_on_a_disc_mask_within_10_percent():
    """A round region (tiles are kept when >= 95 % inside); the outside is flat 255, which must not count."""
    rows = cols = 256
    image, _ = speckle((rows, cols), 4.0, 10)
    y, x = np.mgrid[0:rows, 0:cols]
    disc = (x - 127.5) ** 2 + (y - 127.5) ** 2 <= 120.0 ** 2
    image = np.where(disc, image, 255.0)
    expected = speckle_size_for_radius(radius_for_speckle_size(4.0))
    assert speckle_size_px(image, disc) == pytest.approx(expected, rel=0.10)


def test_speckle_size_errors():
    image, _ = speckle((64, 64), 4.0, 1)
    small = np.zeros((64, 64), dtype=bool)
    small[10:20, 10:40] = True
    with pytest.raises(ValueError, match="at least 16 x 16 px"):
        speckle_size_px(image, small)
    with pytest.raises(ValueError, match="flat"):
        speckle_size_px(np.full((64, 64), 100.0))


# ------------------------------------------------------------------------------------------------------------
# Static-pair noise
# ------------------------------------------------------------------------------------------------------------
READ_GREY = 1.5
ELECTRONS_PER_GREY = 20.0


def clean_pattern(shape=(256, 256), seed=11):
    """A periodic, band-limited speckle rescaled to [20, 235] grey (no clipping after a Fourier shift)."""
    p, _ = speckle(shape, 4.0, seed, periodic=True)
    p = band_limit(p)
    return 20.0 + 215.0 * (p - p.min()) / (p.max() - p.min())


def equalised_pattern(shape=(256, 256), seed=11):
    """A 4 px speckle with its histogram flattened over [10, 240] grey (a pointwise map), so that every grey
    level of the noise model's fit is well populated."""
    p, _ = speckle(shape, 4.0, seed)
    rank = np.argsort(np.argsort(p.ravel())).reshape(shape)
    return 10.0 + 230.0 * (rank + 0.5) / rank.size


def expected_sigma(clean, bit_depth):
    """RMS over pixels of the per-pixel standard deviation the sensor model predicts."""
    return float(np.sqrt(np.mean(noise_sigma_grey(clean, READ_GREY, ELECTRONS_PER_GREY, bit_depth) ** 2)))


def noisy(clean, bit_depth, seed):
    return apply_sensor_noise(clean, read_noise_grey=READ_GREY, electrons_per_grey=ELECTRONS_PER_GREY,
                              bit_depth=bit_depth, seed=seed)


@pytest.mark.parametrize("bit_depth", [8, None])
@pytest.mark.parametrize("seeds", [(1, 2), (3, 4)])
def test_static_pair_sigma_within_5_percent_and_model_within_3_percent(bit_depth, seeds):
    """Read noise 1.5 grey, 20 e-/grey, 8 bit or unquantised: sigma within 5 % of the sensor model's RMS;
    sigma_at(grey) within 3 % of noise_sigma_grey at 40, 120, 200 grey; gain and read noise (with quantisation's
    1/12 grey^2 when rounded) within 10 %."""
    clean = equalised_pattern()
    model = noise_from_static_pair(noisy(clean, bit_depth, seeds[0]), noisy(clean, bit_depth, seeds[1]))
    assert model.source == "static pair"
    assert model.sigma_grey == pytest.approx(expected_sigma(clean, bit_depth), rel=0.05)
    for grey in (40.0, 120.0, 200.0):
        truth = float(noise_sigma_grey(np.array([grey]), READ_GREY, ELECTRONS_PER_GREY, bit_depth)[0])
        assert float(model.sigma_at(grey)) == pytest.approx(truth, rel=0.03)
    assert model.electrons_per_grey == pytest.approx(ELECTRONS_PER_GREY, rel=0.10)
    read = math.sqrt(READ_GREY ** 2 + (1.0 / 12.0 if bit_depth else 0.0))
    assert model.read_noise_grey == pytest.approx(read, rel=0.10)


@pytest.mark.parametrize("bit_depth", [8, None])
def test_static_pair_smooth_illumination_change_sigma_5_percent_change_20_percent(bit_depth):
    """A 0.8-grey cosine of 200 px period added to the second image: sigma stays within 5 % of the model and
    smooth_change_grey (per exposure: RMS of the change / sqrt 2) is within 20 % of the imposed one."""
    clean = clean_pattern()
    a, b = noisy(clean, bit_depth, 3), noisy(clean, bit_depth, 4)
    y, x = np.mgrid[0:256, 0:256]
    change = 0.8 * np.cos(2.0 * np.pi * (x + 0.5 * y) / 200.0)
    model = noise_from_static_pair(a, b + change)
    assert model.sigma_grey == pytest.approx(expected_sigma(clean, bit_depth), rel=0.05)
    imposed = float(np.std(change)) / math.sqrt(2.0)
    assert model.smooth_change_grey == pytest.approx(imposed, rel=0.20)


@pytest.mark.parametrize("bit_depth", [8, None])
def test_static_pair_with_subpixel_motion_sigma_within_5_percent(bit_depth):
    """Second image Fourier-shifted by (0.3, -0.2) px before noise: with motion_xy_px the sigma is within 5 %
    of the model; without it the motion's grad I . delta inflates it by more than 20 %."""
    clean = clean_pattern()
    shifted = fourier_shift(clean, (0.3, -0.2))
    a, b = noisy(clean, bit_depth, 5), noisy(shifted, bit_depth, 6)
    model = noise_from_static_pair(a, b, motion_xy_px=(0.3, -0.2))
    assert model.sigma_grey == pytest.approx(expected_sigma(clean, bit_depth), rel=0.05)
    ignored = noise_from_static_pair(a, b)
    assert ignored.sigma_grey > 1.2 * expected_sigma(clean, bit_depth)


def test_static_pair_errors():
    clean = clean_pattern((64, 64))
    with pytest.raises(ValueError, match="differ in size"):
        noise_from_static_pair(clean, clean[:, :60])
    few = np.zeros((64, 64), dtype=bool)
    few[:20, :20] = True
    with pytest.raises(ValueError, match="at least 1000 are needed"):
        noise_from_static_pair(noisy(clean, None, 1), noisy(clean, None, 2), few)


# ------------------------------------------------------------------------------------------------------------
# Grey statistics
# ------------------------------------------------------------------------------------------------------------
def constructed_image():
    """60 x 50 px of 8-bit values: 137 pixels at 255, 83 at 0, the rest in 1..254."""
    rng = np.random.default_rng(21)
    image = rng.integers(1, 255, size=(60, 50)).astype(np.uint8)
    flat = image.reshape(-1)
    idx = rng.permutation(flat.size)
    flat[idx[:137]] = 255
    flat[idx[137:220]] = 0
    return image


def test_grey_statistics_counts_and_contrast_by_hand():
    image = constructed_image()
    v = image.astype(np.float64)
    stats = grey_statistics(image, bit_depth=8)
    assert stats.pixels == 3000
    assert stats.saturated_fraction == pytest.approx(137 / 3000, abs=1e-15)
    assert stats.zero_fraction == pytest.approx(83 / 3000, abs=1e-15)
    assert stats.mean_grey == pytest.approx(v.mean(), rel=1e-12)
    assert stats.std_grey == pytest.approx(v.std(), rel=1e-12)
    assert stats.contrast == pytest.approx(v.std() / v.mean(), rel=1e-12)
    assert stats.p1_grey == pytest.approx(np.percentile(v, 1.0))
    assert stats.p99_grey == pytest.approx(np.percentile(v, 99.0))
    assert stats.ceiling_grey == 255.0
    assert int(stats.histogram.sum()) == 3000
    # without the bit depth the ceiling is the image maximum (held by 137 px > 0.1 %)
    assert grey_statistics(image).saturated_fraction == pytest.approx(137 / 3000, abs=1e-15)


def test_grey_statistics_of_a_masked_region_by_hand():
    image = constructed_image()
    mask = np.zeros(image.shape, dtype=bool)
    mask[5:40, 10:45] = True
    v = image[mask].astype(np.float64)
    stats = grey_statistics(image, mask, bit_depth=8)
    assert stats.pixels == mask.sum()
    assert stats.saturated_fraction == pytest.approx(np.count_nonzero(v == 255) / v.size, abs=1e-15)
    assert stats.zero_fraction == pytest.approx(np.count_nonzero(v == 0) / v.size, abs=1e-15)
    assert stats.contrast == pytest.approx(v.std() / v.mean(), rel=1e-12)


def test_grey_statistics_16_bit_ceiling_is_not_the_8_bit_one():
    """A 12-bit image stored in 16 bits: with bit_depth=12 only 4095 counts as saturated."""
    image = np.full((40, 40), 2000, dtype=np.uint16)
    image[:4, :] = 4095
    image[4:6, :] = 255
    stats = grey_statistics(image, bit_depth=12)
    assert stats.saturated_fraction == pytest.approx(160 / 1600)
    assert stats.zero_fraction == 0.0


def test_region_mask_errors():
    image = constructed_image()
    with pytest.raises(ValueError, match="does not match the image shape"):
        grey_statistics(image, np.ones((50, 60), dtype=bool))
    with pytest.raises(ValueError, match="must be a boolean array"):
        grey_statistics(image, np.ones(image.shape, dtype=np.uint8))
    with pytest.raises(ValueError, match="selects no pixel"):
        speckle_size_px(image, np.zeros(image.shape, dtype=bool))
    assert region_mask((3, 4), None).all() and region_mask((3, 4), None).shape == (3, 4)


# ------------------------------------------------------------------------------------------------------------
# Pan bound and SSSIG
# ------------------------------------------------------------------------------------------------------------
def test_pan_bound_formula_and_infinite_for_zero_sssig():
    sssig = np.array([0.0, 1.0, 400.0, 2.5e5])
    bound = pan_bound_px(sssig, 2.0)
    assert bound[0] == math.inf
    np.testing.assert_allclose(bound[1:], math.sqrt(2.0) * 2.0 / np.sqrt(sssig[1:]), rtol=1e-14)


@pytest.mark.parametrize("axis", [1, 0])
@pytest.mark.parametrize("period_px", [6.0, 7.0])
def test_sssig_of_a_sinusoid_equals_closed_form_within_2_percent(axis, period_px):
    """f = 100 + A sin(2 pi x / p): 2N / p is an integer for N = 21, so the SSSIG along the wave is exactly
    N^2 A^2 (2 pi / p)^2 / 2; across it 0. Interior subsets (8 px from the edges), 2 %."""
    A, N = 20.0, 21
    rows, cols = 96, 128
    coord = np.arange(cols if axis == 1 else rows, dtype=np.float64)
    wave = 100.0 + A * np.sin(2.0 * np.pi * coord / period_px + 0.3)
    image = np.tile(wave, (rows, 1)) if axis == 1 else np.tile(wave[:, None], (1, cols))
    x, y = grid_points((rows, cols), N // 2 + 8, 3)
    sx, sy, mig = subset_sssig(image, x, y, N)
    along, across = (sx, sy) if axis == 1 else (sy, sx)
    closed = N * N * A * A * (2.0 * np.pi / period_px) ** 2 / 2.0
    np.testing.assert_allclose(along, closed, rtol=0.02)
    assert np.max(across) <= 1e-9 * closed
    # MIG: mean |A w cos| = A w 2 / pi over whole periods (N covers 2N/p half periods exactly)
    np.testing.assert_allclose(mig, A * 2.0 * np.pi / period_px * 2.0 / np.pi, rtol=0.02)


def test_sssig_of_an_8_px_sinusoid_matches_the_exact_gradient_sum_within_2_percent():
    """p = 8, N = 21: each subset's SSSIG equals N sum (A w cos(w x))^2 over its 21 columns (by hand), and the
    average over all phases equals N^2 A^2 w^2 / 2, both within 2 %."""
    A, N, p = 20.0, 21, 8.0
    w = 2.0 * np.pi / p
    rows, cols = 64, 128
    x_axis = np.arange(cols, dtype=np.float64)
    image = np.tile(100.0 + A * np.sin(w * x_axis), (rows, 1))
    cx = np.arange(N // 2 + 8, cols - N // 2 - 8)
    cy = np.full(cx.size, rows // 2)
    sx, _, _ = subset_sssig(image, cx, cy, N)
    grad = A * w * np.cos(w * x_axis)
    by_hand = np.array([N * np.sum(grad[c - N // 2:c + N // 2 + 1] ** 2) for c in cx])
    np.testing.assert_allclose(sx, by_hand, rtol=0.02)
    assert np.mean(sx[:8 * (cx.size // 8)]) == pytest.approx(N * N * A * A * w * w / 2.0, rel=0.02)


def test_sssig_of_analytic_speckle_matches_its_exact_gradient_within_3_percent():
    """The Gaussian-blob pattern's exact gradient (central difference of the analytic pattern with h = 1e-4 px)
    summed over 21 px subsets agrees with the SSSIG read from the sampled 5 px speckle image within 3 %."""
    shape = (96, 96)
    image, pattern = speckle(shape, 5.0, 12)
    N, h = 21, 1e-4
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    pts = np.stack([x, y], axis=-1)
    gx = (pattern.evaluate(pts + [h, 0.0]) - pattern.evaluate(pts - [h, 0.0])) / (2 * h)
    gy = (pattern.evaluate(pts + [0.0, h]) - pattern.evaluate(pts - [0.0, h])) / (2 * h)
    cx, cy = grid_points(shape, N // 2 + 6, 7)
    sx, sy, _ = subset_sssig(image, cx, cy, N)
    half = N // 2
    ex = np.array([np.sum(gx[j - half:j + half + 1, i - half:i + half + 1] ** 2) for i, j in zip(cx, cy)])
    ey = np.array([np.sum(gy[j - half:j + half + 1, i - half:i + half + 1] ** 2) for i, j in zip(cx, cy)])
    np.testing.assert_allclose(sx, ex, rtol=0.03)
    np.testing.assert_allclose(sy, ey, rtol=0.03)


@pytest.mark.parametrize("kind", ["sinusoid", "speckle"])
def test_sssig_noise_correction_within_5_percent_of_the_clean_value(kind):
    """White noise of 4 grey raises the mean SSSIG by > 10 %; passing noise_sigma_grey=4 brings the mean over
    ~600 subsets back within 5 % of the clean image's."""
    shape, N, sigma = (128, 128), 21, 4.0
    if kind == "sinusoid":
        image = np.tile(100.0 + 20.0 * np.sin(2.0 * np.pi * np.arange(128) / 8.0), (128, 1))
        axes = (0,)
    else:
        image, _ = speckle(shape, 4.0, 3)
        axes = (0, 1)
    x, y = grid_points(shape, N // 2, 4)
    clean = subset_sssig(image, x, y, N)
    with_noise = image + np.random.default_rng(7).normal(0.0, sigma, shape)
    raw = subset_sssig(with_noise, x, y, N)
    corrected = subset_sssig(with_noise, x, y, N, noise_sigma_grey=sigma)
    for k in axes:
        assert np.mean(raw[k]) > 1.10 * np.mean(clean[k])
        assert np.mean(corrected[k]) == pytest.approx(np.mean(clean[k]), rel=0.05)
    if kind == "sinusoid":     # across the wave only noise: the correction removes (nearly) all of it
        assert np.mean(corrected[1]) < 0.1 * np.mean(raw[1])


def test_subset_sssig_errors():
    image = np.zeros((40, 40))
    with pytest.raises(ValueError, match="leaves the 40 x 40 px image"):
        subset_sssig(image, [5], [20], 21)
    with pytest.raises(ValueError, match="odd integer >= 3"):
        subset_sssig(image, [20], [20], 20)


def test_pan_bound_is_a_lower_bound_of_first_order_dic_noise_within_factor_1_6():
    """Static pairs of analytic 4 px speckle, each image with independent Gaussian noise of 2 grey (no
    quantisation): the scatter of u (and v) of first-order DIC (subset 21, step 8), pooled over three noise
    realisations, is >= the RMS over points of the Pan bound and below 1.6 times it."""
    shape, sigma = (288, 288), 2.0
    settings = DICSettings(subset_size=21, step=8, order=1)
    image, _ = speckle(shape, 4.0, 2)
    var_u, var_v, bound2_u, bound2_v = [], [], [], []
    for k in range(3):
        rng = np.random.default_rng(100 + k)
        reference = image + rng.normal(0.0, sigma, shape)
        repeat = image + rng.normal(0.0, sigma, shape)
        result = correlate(reference, repeat, settings)
        ok = result.converged
        assert ok.mean() > 0.95
        sx, sy, _ = subset_sssig(reference, result.x[ok], result.y[ok], 21, noise_sigma_grey=sigma)
        var_u.append(np.var(result.u[ok]))
        var_v.append(np.var(result.v[ok]))
        bound2_u.append(np.mean(pan_bound_px(sx, sigma) ** 2))
        bound2_v.append(np.mean(pan_bound_px(sy, sigma) ** 2))
    std_u, bound_u = math.sqrt(np.mean(var_u)), math.sqrt(np.mean(bound2_u))
    std_v, bound_v = math.sqrt(np.mean(var_v)), math.sqrt(np.mean(bound2_v))
    assert bound_u <= std_u <= 1.6 * bound_u
    assert bound_v <= std_v <= 1.6 * bound_v


# ------------------------------------------------------------------------------------------------------------
# Subset advice
# ------------------------------------------------------------------------------------------------------------
def test_subset_advice_too_fine_for_1_5_px_speckles():
    """White noise blurred by a 0.55 px Gaussian: ~1.5 px speckles (< 2 px) are 'too fine' whatever the noise."""
    rng = np.random.default_rng(5)
    raw = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (128, 128)), 0.55)
    image = 128.0 + 30.0 * raw / raw.std()
    size = speckle_size_px(image)
    assert 1.2 < size < 1.9
    x, y = grid_points(image.shape, 24, 8)
    advice = subset_advice(image, x, y, 1.0, size)
    assert advice.verdict == "too fine"
    assert "under-sampled" in advice.message


def test_subset_advice_ok_for_4_px_speckles_with_little_noise():
    """4 px speckle, 0.5 grey noise: the speckle rule (3 speckles across) sets the subset, the smallest odd
    width >= 3 x the measured size; the Pan bound (from the analytic pattern, clean) is then below 0.01 px."""
    shape, sigma = (128, 128), 0.5
    image, _ = speckle(shape, 4.0, 3)
    size = speckle_size_px(image)
    noisy_image = image + np.random.default_rng(1).normal(0.0, sigma, shape)
    x, y = grid_points(shape, 24, 8)
    advice = subset_advice(noisy_image, x, y, sigma, size)
    assert advice.verdict == "ok"
    smallest_odd = int(math.ceil(3.0 * size))
    smallest_odd += 1 - smallest_odd % 2
    assert advice.subset_px == advice.needed_px == max(11, smallest_odd)
    sx, sy, _ = subset_sssig(image, x, y, advice.subset_px)
    assert np.median(np.maximum(pan_bound_px(sx, sigma), pan_bound_px(sy, sigma))) <= 0.01


def test_subset_advice_ok_grows_with_noise():
    """With 4 grey of noise the Pan bound, not the speckle rule, sets the subset: larger than at 0.5 grey, and
    the bound at the advised size is <= 0.01 px while two pixels less is above it (clean pattern, 10 %)."""
    shape, sigma = (128, 128), 4.0
    image, _ = speckle(shape, 4.0, 3)
    size = speckle_size_px(image)
    noisy_image = image + np.random.default_rng(1).normal(0.0, sigma, shape)
    x, y = grid_points(shape, 24, 8)
    advice = subset_advice(noisy_image, x, y, sigma, size)
    assert advice.verdict == "ok" and advice.subset_px > 3.0 * size + 2

    def median_bound(n):
        sx, sy, _ = subset_sssig(image, x, y, n)
        return float(np.median(np.maximum(pan_bound_px(sx, sigma), pan_bound_px(sy, sigma))))

    assert median_bound(advice.subset_px) <= 0.01 * 1.10
    assert median_bound(advice.subset_px - 2) > 0.01 * 0.90


def test_subset_advice_too_coarse_for_40_px_speckles_in_a_128_px_image():
    """40 px blobs in 128 px: no subset fits; the subset it would need is named and exceeds the image."""
    shape, sigma = (128, 128), 2.0
    image, _ = speckle(shape, 40.0, 3)
    noisy_image = image + np.random.default_rng(1).normal(0.0, sigma, shape)
    x, y = grid_points(shape, 60, 4)
    advice = subset_advice(noisy_image, x, y, sigma, 40.0)
    assert advice.verdict == "too coarse"
    assert advice.subset_px is None
    assert advice.needed_px > 128
    assert str(advice.needed_px) in advice.message
