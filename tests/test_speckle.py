"""Tests for scenes.surfaces.speckle: the truth-side speckle texture."""
import numpy as np
import pytest

from scenes.surfaces.speckle import speckle_pattern, speckle_size_from_pattern, texels_for

SHAPE = (512, 512)


def _energy_fraction_above(pattern, cutoff_cycles_per_texel):
    """Fraction of the pattern's variance (AC power) at radial frequencies above the cutoff."""
    power = np.abs(np.fft.fft2(pattern - pattern.mean())) ** 2
    fr = np.fft.fftfreq(pattern.shape[0])[:, None]
    fc = np.fft.fftfreq(pattern.shape[1])[None, :]
    return power[np.hypot(fr, fc) > cutoff_cycles_per_texel].sum() / power.sum()


def test_shape_dtype_and_range():
    pattern = speckle_pattern((256, 384), 8.0, seed=1)
    assert pattern.shape == (256, 384)
    assert pattern.dtype == np.float32
    assert pattern.min() >= 0.0 and pattern.max() <= 1.0
    # contrast 1 around mean 0.5 uses the full range: black speckle cores and white background
    assert pattern.min() < 0.02 and pattern.max() > 0.98


def test_same_seed_identical_different_seed_different():
    a = speckle_pattern(SHAPE, 6.0, seed=7)
    b = speckle_pattern(SHAPE, 6.0, seed=7)
    c = speckle_pattern(SHAPE, 6.0, seed=8)
    np.testing.assert_array_equal(a, b)
    assert np.mean(np.abs(a - c)) > 0.1


@pytest.mark.parametrize("size_texels", [6.0, 12.0])
def test_requested_speckle_size_is_honoured(size_texels):
    pattern = speckle_pattern(SHAPE, size_texels, seed=3)
    estimated = speckle_size_from_pattern(pattern)
    assert abs(estimated - size_texels) <= 0.25 * size_texels, estimated


def test_size_estimate_scales_with_requested_size():
    small = speckle_size_from_pattern(speckle_pattern(SHAPE, 5.0, seed=4))
    large = speckle_size_from_pattern(speckle_pattern(SHAPE, 15.0, seed=4))
    assert 2.5 < large / small < 3.5


@pytest.mark.parametrize("density", [0.3, 0.5, 0.65])
def test_density_is_honoured(density):
    mean = 0.5
    pattern = speckle_pattern(SHAPE, 8.0, density=density, mean=mean, seed=5)
    dark_fraction = np.mean(pattern < mean)
    assert abs(dark_fraction - density) <= 0.1, dark_fraction


def test_contrast_and_mean_set_the_grey_range():
    pattern = speckle_pattern(SHAPE, 8.0, contrast=0.4, mean=0.6, seed=2)
    assert pattern.min() >= 0.4 - 1e-6 and pattern.max() <= 0.8 + 1e-6
    assert pattern.min() < 0.41 and pattern.max() > 0.79


def test_out_of_range_grey_is_clipped():
    pattern = speckle_pattern(SHAPE, 8.0, contrast=1.0, mean=0.8, seed=2)
    assert pattern.max() == pytest.approx(1.0)
    assert pattern.min() == pytest.approx(0.3, abs=0.01)


def test_texture_is_band_limited():
    pattern = speckle_pattern(SHAPE, 8.0, seed=6).astype(np.float64)
    assert _energy_fraction_above(pattern, 0.25) < 0.01
    # the Gaussian low-pass is what does it: without it the hard-edged disks leak far more
    raw = speckle_pattern(SHAPE, 8.0, seed=6, smoothing_texels=0.0).astype(np.float64)
    assert _energy_fraction_above(raw, 0.25) > 10 * _energy_fraction_above(pattern, 0.25)


def test_pattern_is_periodic():
    # FFT convolution wraps around, so the seam between opposite edges looks like any interior row step.
    pattern = speckle_pattern(SHAPE, 8.0, seed=9).astype(np.float64)
    interior_step = np.mean(np.abs(np.diff(pattern, axis=0)))
    seam_step = np.mean(np.abs(pattern[0] - pattern[-1]))
    assert seam_step < 2.0 * interior_step


def test_texels_for():
    assert texels_for(4.0, 3.0) == pytest.approx(12.0)
    with pytest.raises(ValueError, match="texels_per_px"):
        texels_for(4.0, 0.0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(speckle_size_texels=1.5), "speckle_size_texels"),
    (dict(speckle_size_texels=float("nan")), "speckle_size_texels"),
    (dict(density=0.0), "density"),
    (dict(density=1.0), "density"),
    (dict(contrast=0.0), "contrast"),
    (dict(mean=1.5), "mean"),
    (dict(smoothing_texels=-1.0), "smoothing_texels"),
    (dict(shape_texels=(0, 64)), "shape_texels"),
    (dict(shape_texels=(64,)), "shape_texels"),
    (dict(shape_texels=(64.5, 64)), "shape_texels"),
    (dict(shape_texels=(16, 16), speckle_size_texels=20.0), "does not fit"),
])
def test_bad_input_raises(kwargs, match):
    args = dict(shape_texels=(64, 64), speckle_size_texels=4.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        speckle_pattern(**args)


def test_size_estimate_rejects_bad_patterns():
    with pytest.raises(ValueError, match="flat"):
        speckle_size_from_pattern(np.ones((32, 32)))
    with pytest.raises(ValueError, match="2-D"):
        speckle_size_from_pattern(np.ones(32))
    bad = speckle_pattern((64, 64), 4.0).astype(np.float64)
    bad[3, 4] = np.nan
    with pytest.raises(ValueError, match="1 non-finite"):
        speckle_size_from_pattern(bad)
