"""Interpolation-bias prediction (measurement.uncertainty.bias) against the engine whose bias it predicts.

References, none of them the code under test: scipy.ndimage's spline interpolation and the engine's own spline
evaluation (Thevenaz weights) for the transfer function; a pure tone's phase after scipy's spline resampling
for the spectral formula; and, for the bias itself, :func:`measurement.dic.correlate` on noise-free pairs that
are exact sub-pixel translates: a periodic band-limited speckle Fourier-shifted, then both images cropped to
their middle, so that neither the engine nor the prediction sees a periodic image.

Tolerances come from what the first-order theory supports (module notes of the bias module): per point it
leaves 0.2-5 % (rms) of the measured bias on 33 px subsets, so 8 % is asked; the mean curve from a region's
spectrum is within 2-6 % of its peak, so 10 % is asked; the bound carries a 10 % margin and must cover >= 95 %
of the points (measured 98-100 %). Points keep their subsets >= 16 px from the image border, where the engine's
mirror-boundary spline differs from the exact translate.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from scipy import ndimage

from measurement.dic import DICSettings, correlate
from measurement.dic.bspline import interpolate, prefilter
from measurement.uncertainty.bias import (DEFAULT_SHIFTS_PX, bias_bound_px, bias_curves_px, interpolant_transfer,
                                          translation_bias_px)
from scenes.image_pairs.fourier_shift import band_limit, fourier_shift
from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size

SHIFTS_PX = np.round(np.arange(1, 10) * 0.1, 10)
SUBSET_PX = 33
FULL, CROP = 448, 256          # the periodic pattern and the middle part both images keep
BORDER_GAP_PX = 16
CASES = [(s, i) for s in (2.5, 4.0, 8.0) for i in ("biquintic", "bicubic")]


@lru_cache(maxsize=None)
def _pattern(speckle_px: float) -> np.ndarray:
    pattern = gaussian_speckle(extent_for_shape((FULL, FULL)), radius_for_speckle_size(speckle_px), 0.5, seed=7,
                               mean_grey=128.0, std_grey=30.0, periodic=True)
    return pattern.render_reference((FULL, FULL))


def _crop(image: np.ndarray) -> np.ndarray:
    start = (FULL - CROP) // 2
    return np.ascontiguousarray(image[start:start + CROP, start:start + CROP])


@lru_cache(maxsize=None)
def _measured(speckle_px: float, interpolation: str, axis: int = 0, order: int = 1, shifts=tuple(SHIFTS_PX)):
    """Reference crop, POIs and the engine's error (estimate - truth) of u (axis 0) or v (axis 1), (N, T)."""
    pattern = _pattern(speckle_px)
    reference = _crop(band_limit(pattern))
    margin = SUBSET_PX // 2 + BORDER_GAP_PX
    settings = DICSettings(subset_size=SUBSET_PX, step=12, order=order, interpolation=interpolation,
                           tolerance_px=1e-6, max_iterations=100)
    errors = []
    for t in shifts:
        shift = (t, 0.0) if axis == 0 else (0.0, t)
        deformed = _crop(fourier_shift(pattern, shift))
        result = correlate(reference, deformed, settings, roi=(margin, margin, CROP - margin, CROP - margin),
                           initial_parameters=lambda x, y: (0.0 * x + shift[0], 0.0 * y + shift[1]))
        assert result.converged.all()
        errors.append((result.u if axis == 0 else result.v) - t)
    return reference, result.x, result.y, np.array(errors).T


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


# --- transfer function ------------------------------------------------------------------------------------

@pytest.mark.parametrize("degree", [3, 5])
def test_transfer_function_is_scipys_spline_resampling(degree):
    # Samples of exp(i w n) on a period of 64 px, resampled at n - t by scipy's spline (periodic boundary):
    # H exp(i w n) by the definition of H.
    n = np.arange(64)
    for k in (1, 5, 13, 22, 31):
        f = k / 64
        for t in (0.1, 0.37, 0.5, -0.2, 1.3):
            samples = np.exp(2j * np.pi * f * n)
            resampled = sum(part * ndimage.map_coordinates(getattr(samples, name), [n - t], order=degree,
                                                           mode="grid-wrap")
                            for part, name in ((1.0, "real"), (1j, "imag")))
            expected = resampled / samples
            assert np.abs(expected - interpolant_transfer(degree, f, t)).max() < 1e-12


@pytest.mark.parametrize("degree", [3, 5])
def test_transfer_derivative_is_the_engines_spline_gradient(degree):
    # d/dt of H(f, t) exp(i w n) is minus the interpolant's gradient at n - t; the engine's evaluation of a cosine
    # image (constant along y, far from the mirror boundaries) gives that gradient independently.
    f, t = 0.137, 0.29
    image = np.tile(np.cos(2 * np.pi * f * np.arange(200)), (12, 1))
    spline = prefilter(image, degree)
    n = np.arange(80.0, 120.0)
    _, grad_x, _ = interpolate(spline, n - t, np.full_like(n, 6.0))
    expected = -np.real(interpolant_transfer(degree, f, t, derivative=True) * np.exp(2j * np.pi * f * n))
    assert np.abs(grad_x - expected).max() < 1e-9


@pytest.mark.parametrize("degree", [3, 5])
def test_transfer_error_falls_as_the_splines_approximation_order(degree):
    # The cardinal spline of degree p reproduces polynomials of degree p: its error falls as f^(p + 1).
    t = 0.3
    error = [abs(interpolant_transfer(degree, f, t) - np.exp(-2j * np.pi * f * t)) for f in (0.02, 0.04)]
    assert 0.9 * 2 ** (degree + 1) < error[1] / error[0] < 1.1 * 2 ** (degree + 1)
    assert interpolant_transfer(degree, 0.21, 0.0) == pytest.approx(1.0, abs=1e-14)


@pytest.mark.parametrize("interpolation,degree", [("bicubic", 3), ("biquintic", 5)])
def test_pure_tone_bias_is_minus_the_phase_error_over_the_frequency(interpolation, degree):
    # A tone cos(w x) translated by t and resampled by scipy's spline at n + t reads cos(w n + phi): matching
    # it moves the estimate by -phi / w. Equation (2) with all the power at +-f0 must say the same, to first
    # order in the interpolation error (~1 % here).
    f0, size = 0.2, 40
    n = np.arange(size)
    spectrum = np.zeros((8, size))
    spectrum[0, [8, size - 8]] = 1.0                               # f0 = 8 / 40 cycles/px along x
    predicted = translation_bias_px(spectrum, [0.15, 0.3, 0.45], interpolation, spectrum=True)[:, 0]
    for t, bias in zip((0.15, 0.3, 0.45), predicted):
        deformed = np.cos(2 * np.pi * f0 * (n - t))
        resampled = ndimage.map_coordinates(deformed, [n + t], order=degree, mode="grid-wrap")
        phase = np.angle(np.sum(resampled * np.exp(-2j * np.pi * f0 * n)))
        assert bias == pytest.approx(-phase / (2 * np.pi * f0), rel=0.03)
        assert abs(bias) > 1e-5                                    # not zero against zero


# --- bias of the engine -----------------------------------------------------------------------------------

@pytest.mark.parametrize("speckle_px,interpolation", CASES)
def test_mean_bias_curve_is_the_spectral_prediction(speckle_px, interpolation):
    reference, xs, ys, errors = _measured(speckle_px, interpolation)
    measured = errors.mean(axis=0)
    peak = np.abs(measured).max()
    h = SUBSET_PX // 2
    region = reference[ys.min() - h:ys.max() + h + 1, xs.min() - h:xs.max() + h + 1]
    from_region = translation_bias_px(region, SHIFTS_PX, interpolation)[:, 0]
    print(f"{speckle_px} px {interpolation}: peak {peak:.3g} px, "
          f"region: max |prediction - measured| / peak {np.abs(from_region - measured).max() / peak:.3f}")
    assert np.abs(from_region - measured).max() <= 0.10 * peak
    # The subsets' own (Hann) spectra, averaged: a 33 px window smooths the spectrum towards the high
    # frequencies, where the phase error grows as f^(p + 2): fair on 2.5-4 px speckles, too high on 8 px.
    subsets = np.stack([reference[y - h:y + h + 1, x - h:x + h + 1] for x, y in zip(xs, ys)])
    from_subsets = translation_bias_px(subsets, SHIFTS_PX, interpolation)[..., 0].mean(axis=0)
    ratio = np.abs(from_subsets).max() / peak
    print(f"    subsets: max |mean - measured| / peak {np.abs(from_subsets - measured).max() / peak:.3f}, "
          f"peak ratio {ratio:.2f}")
    if speckle_px < 5:
        assert np.abs(from_subsets - measured).max() <= 0.20 * peak
    else:
        assert 1.0 <= ratio <= 2.0


@pytest.mark.parametrize("speckle_px,interpolation", CASES)
def test_per_point_bias_curves_match_the_engine(speckle_px, interpolation):
    reference, xs, ys, errors = _measured(speckle_px, interpolation)
    predicted = bias_curves_px(reference, xs, ys, SUBSET_PX, SHIFTS_PX, interpolation)[:, :, 0]
    ratio = _rms(predicted - errors) / _rms(errors)
    # The points differ by much more than the error of the prediction: it is per point, not a mean.
    spread = _rms(errors - errors.mean(axis=0)) / _rms(errors)
    print(f"{speckle_px} px {interpolation}: rms error {ratio:.3f} of rms bias; point-to-point spread {spread:.2f}")
    assert ratio <= 0.08
    assert spread >= 3 * ratio


@pytest.mark.parametrize("speckle_px,interpolation", CASES)
def test_bias_bound_covers_the_measured_bias(speckle_px, interpolation):
    reference, xs, ys, errors = _measured(speckle_px, interpolation)
    bound = bias_bound_px(reference, xs, ys, SUBSET_PX, interpolation)
    covered = np.mean(np.abs(errors).max(axis=1) <= bound[:, 0])
    # ... and it is a bound on this point, not a blanket figure: 2x the largest |bias| of the point beats it.
    loose = np.mean(bound[:, 0] <= 2.0 * np.abs(errors).max(axis=1))
    print(f"{speckle_px} px {interpolation}: bound covers {covered:.3f} of the points; within 2x at {loose:.3f}")
    assert covered >= 0.95
    assert loose >= 0.95


def test_a_points_curve_is_not_antisymmetric_about_half_a_pixel():
    # Only the mean curve is odd about t = 1/2; a point's window terms add an even part (8 px speckle: ~75 % of
    # the curve) that the prediction reproduces, so the bound searches the whole period, not [0, 1/2].
    reference, xs, ys, errors = _measured(8.0, "bicubic")
    pairs = [(k, len(SHIFTS_PX) - 1 - k) for k in range(4)] + [(4, 4)]          # t and 1 - t, and t = 1/2
    even = np.stack([errors[:, a] + errors[:, b] for a, b in pairs], axis=1)
    predicted = bias_curves_px(reference, xs, ys, SUBSET_PX, SHIFTS_PX, "bicubic")[:, :, 0]
    predicted_even = np.stack([predicted[:, a] + predicted[:, b] for a, b in pairs], axis=1)
    assert _rms(even) >= 0.5 * _rms(errors)
    assert np.abs(even.mean(axis=0)).max() <= 0.1 * _rms(even)
    assert _rms(predicted_even - even) <= 0.1 * _rms(even)
    half = np.abs(errors[:, :5]).max(axis=1)
    assert np.mean(half < 0.8 * np.abs(errors).max(axis=1)) >= 0.2
    assert DEFAULT_SHIFTS_PX.min() <= 0.05 and DEFAULT_SHIFTS_PX.max() >= 0.95


def test_bias_of_v_comes_from_the_shift_along_y():
    reference, xs, ys, errors_v = _measured(4.0, "biquintic", axis=1)
    predicted = bias_curves_px(reference, xs, ys, SUBSET_PX, SHIFTS_PX, "biquintic")
    spread = _rms(errors_v - errors_v.mean(axis=0))        # what tells one point from another
    assert _rms(predicted[:, :, 1] - errors_v) <= 0.1 * spread
    # the u prediction (the same pattern's shift along x) has the same mean but other points' curves
    assert _rms(predicted[:, :, 0] - errors_v) >= 0.5 * spread


def test_second_order_shape_function():
    shifts = (0.2, 0.5, 0.7)
    reference, xs, ys, errors = _measured(2.5, "bicubic", order=2, shifts=shifts)
    second = bias_curves_px(reference, xs, ys, SUBSET_PX, shifts, "bicubic", order=2)[:, :, 0]
    first = bias_curves_px(reference, xs, ys, SUBSET_PX, shifts, "bicubic", order=1)[:, :, 0]
    spread = _rms(errors - errors.mean(axis=0))
    assert _rms(second - errors) <= 0.1 * spread
    # the shape function matters per point: the first-order prediction misses an order-2 run
    assert _rms(first - errors) >= 0.5 * spread


# --- edge cases -------------------------------------------------------------------------------------------

def test_unusable_points_are_nan():
    rng = np.random.default_rng(3)
    image = ndimage.gaussian_filter(rng.normal(128.0, 40.0, (120, 140)), 1.2)
    image[:, 100:] = 77.0                                                          # flat on the right
    x = np.array([50, 5, 120, 60])
    y = np.array([60, 60, 60, 115])
    bound = bias_bound_px(image, x, y, 21)
    assert np.isfinite(bound[0]).all() and (bound[0] > 0).all()
    assert np.isnan(bound[1:]).all()          # leaves the image (left, bottom) or no texture (flat)
    assert bias_curves_px(image, x, y, 21, [0.25]).shape == (4, 1, 2)


def test_invalid_inputs_raise():
    image = np.random.default_rng(0).normal(size=(60, 60))
    with pytest.raises(ValueError, match="spline degree must be 3 or 5"):
        interpolant_transfer(4, 0.1, 0.2)
    with pytest.raises(ValueError, match="must be finite"):
        interpolant_transfer(3, np.nan, 0.2)
    with pytest.raises(ValueError, match="interpolation must be one of"):
        bias_bound_px(image, [30], [30], 21, "bilinear")
    with pytest.raises(ValueError, match="odd integer"):
        bias_bound_px(image, [30], [30], 20)
    with pytest.raises(ValueError, match="finite integers"):
        bias_bound_px(image, [30.5], [30], 21)
    with pytest.raises(ValueError, match="same length"):
        bias_bound_px(image, [30, 31], [30], 21)
    with pytest.raises(ValueError, match="NaN or infinite"):
        bias_bound_px(np.where(image > 2, np.nan, image), [30], [30], 21)
    with pytest.raises(ValueError, match="order must be 1 or 2"):
        bias_curves_px(image, [30], [30], 21, order=3)
    with pytest.raises(ValueError, match="relative_margin"):
        bias_bound_px(image, [30], [30], 21, relative_margin=-0.1)
    with pytest.raises(ValueError, match="shifts_px"):
        bias_curves_px(image, [30], [30], 21, [])
    with pytest.raises(ValueError, match="cannot be negative"):
        translation_bias_px(-np.ones((8, 8)), [0.2], spectrum=True)
    with pytest.raises(ValueError, match="rows, cols >= 4"):
        translation_bias_px(np.ones(8), [0.2])
