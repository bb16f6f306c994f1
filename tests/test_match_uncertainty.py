"""The per-point uncertainty of a match (measurement/uncertainty/match.py) against the scatter it claims to predict.

Reference: the same exact sub-pixel translation of a band-limited speckle (Fourier shift) re-noised with 12
independent seeds; each point's error about its own mean over the seeds is its random error (the interpolation
bias, the same in every draw, drops out). The estimator sees one noisy pair at a time and never the truth.
Claims (issue 36's goal for the random part): std(error / sigma) within [0.9, 1.1] and the 95 % interval covering
93-97 % of the points, per component.
"""
import numpy as np
import pytest

from measurement.dic import DICSettings, correlate
from measurement.speckle_quality import NoiseModel
from measurement.uncertainty.match import (FLAG_NONE, FLAG_RESIDUAL, dic_uncertainty, match_uncertainty,
                                           noise_from_residuals, reference_subsets)
from scenes.noise import apply_sensor_noise
from scenes.synthetic_images import fourier_shifted_pair

SHIFT = (0.3, 0.45)
ROI = (40, 40, 160, 160)
SEEDS = 12


def _draws(speckle_px, read_grey, order, subset, gain=None, seeds=SEEDS):
    reference, moved = fourier_shifted_pair((200, 200), speckle_px, SHIFT, seed=1, mean_grey=160.0, std_grey=25)
    settings = DICSettings(subset_size=subset, step=10, order=order)
    model = NoiseModel(read_grey, read_grey, gain, "given")
    out = []
    for s in range(seeds):
        ref = apply_sensor_noise(reference, read_noise_grey=read_grey, electrons_per_grey=gain, bit_depth=None,
                                 seed=2 * s)
        mov = apply_sensor_noise(moved, read_noise_grey=read_grey, electrons_per_grey=gain, bit_depth=None,
                                 seed=2 * s + 1)
        result = correlate(ref, mov, settings, roi=ROI,
                           initial_parameters=lambda x, y: (0 * x + SHIFT[0], 0 * y + SHIFT[1]))
        subsets = reference_subsets(ref, result.x, result.y, subset, order, model)
        out.append((result, match_uncertainty(subsets, result), ref))
    return out


def _z(draws, which="total"):
    errors = np.array([np.column_stack([r.u, r.v]) for r, _, _ in draws])
    if which == "total":
        sigmas = np.array([np.column_stack([u.sigma_u_px, u.sigma_v_px]) for _, u, _ in draws])
    else:                      # the target image's part only: an estimator that forgets the reference's noise
        sigmas = np.array([np.sqrt(np.einsum("kii->ki", u.cov_target_px2)) for _, u, _ in draws])
    keep = np.all(np.isfinite(errors), axis=(0, 2)) & np.all(np.isfinite(sigmas), axis=(0, 2))
    n = errors.shape[0]
    deviation = (errors - errors.mean(axis=0))[:, keep] * np.sqrt(n / (n - 1))
    return deviation / sigmas[:, keep]


@pytest.mark.parametrize("speckle_px, read_grey, order, subset", [
    (4.0, 2.0, 1, 21), (2.5, 5.0, 2, 41), (8.0, 0.5, 1, 21), (2.5, 0.5, 1, 21), (4.0, 5.0, 2, 41)])
def test_sigma_of_u_and_v_is_honest(speckle_px, read_grey, order, subset):
    """std(error / sigma) in [0.9, 1.1] and 95 % coverage in [0.93, 0.97] for u and v."""
    z = _z(_draws(speckle_px, read_grey, order, subset))
    spread = z.std(axis=(0, 1))
    coverage = np.mean(np.abs(z) < 1.959964, axis=(0, 1))
    print(f"speckle {speckle_px} px, noise {read_grey} grey, order {order}, subset {subset}: std(z) {spread.round(3)}, "
          f"95 % coverage {coverage.round(3)} over {z.shape[1]} points x {z.shape[0]} draws")
    assert np.all((spread > 0.9) & (spread < 1.1))
    assert np.all((coverage > 0.93) & (coverage < 0.97))


def test_an_estimator_that_forgets_the_reference_noise_fails_the_claim():
    """The claim above discriminates: the target image's part alone under-states sigma by ~sqrt(2)."""
    z = _z(_draws(4.0, 2.0, 1, 21), which="target only")
    assert np.all(z.std(axis=(0, 1)) > 1.25)


def test_signal_dependent_noise_is_honest():
    """Shot noise (4 electrons per grey on a mean of 160 grey: sigma^2 = 1 + I / 4) with its model: same claims."""
    z = _z(_draws(4.0, 1.0, 1, 21, gain=4.0))
    spread = z.std(axis=(0, 1))
    assert np.all((spread > 0.9) & (spread < 1.1)), spread


def test_noise_from_residuals_recovers_the_noise():
    """The noise fitted to one pair's residuals is within 5 % of the true 2 grey (4 px speckle, first order)."""
    result, _, ref = _draws(4.0, 2.0, 1, 21, seeds=1)[0]
    model = noise_from_residuals(ref, result.x, result.y, result)
    assert model.source == "match residuals"
    assert abs(model.sigma_at(128.0) / 2.0 - 1.0) < 0.05, model


def test_the_residual_check_flags_an_occluded_region_only():
    """A flat patch pasted into the target (an occlusion the shape function cannot follow) flags the subsets
    that overlap it by a quarter or more; elsewhere at most 5 % of the points are flagged."""
    reference, moved = fourier_shifted_pair((200, 200), 4.0, SHIFT, seed=1, std_grey=25)
    ref = apply_sensor_noise(reference, read_noise_grey=2.0, bit_depth=None, seed=1)
    mov = apply_sensor_noise(moved, read_noise_grey=2.0, bit_depth=None, seed=2)
    mov[90:110, 90:110] = 128.0 + np.random.default_rng(0).normal(0, 2.0, (20, 20))
    result = correlate(ref, mov, DICSettings(subset_size=21, step=10), roi=ROI,
                       initial_parameters=lambda x, y: (0 * x + SHIFT[0], 0 * y + SHIFT[1]))
    unc = dic_uncertainty(ref, result, NoiseModel(2.0, 2.0, None, "given"))
    overlap = (np.clip(np.minimum(result.x + 11, 110) - np.maximum(result.x - 10, 90), 0, None)
               * np.clip(np.minimum(result.y + 11, 110) - np.maximum(result.y - 10, 90), 0, None)) / 21 ** 2
    occluded = overlap >= 0.25
    clear = overlap == 0
    assert occluded.sum() >= 4
    assert np.all(unc.flag[occluded & result.converged] == FLAG_RESIDUAL)
    assert np.mean(unc.flag[clear] != FLAG_NONE) <= 0.05


def test_a_match_of_another_grid_is_refused():
    result, _, ref = _draws(4.0, 2.0, 1, 21, seeds=1)[0]
    subsets = reference_subsets(ref, result.x[:-1], result.y[:-1], 21, 1, NoiseModel(2.0, 2.0, None, "given"))
    with pytest.raises(ValueError, match="points of interest differ"):
        match_uncertainty(subsets, result)


@pytest.mark.parametrize("speckle_px, read_grey, order, subset", [(4.0, 2.0, 1, 21), (2.5, 5.0, 2, 41)])
def test_static_repeat_sigma_from_the_reference_alone_is_honest(speckle_px, read_grey, order, subset):
    """A static repeat (the same pattern exposed twice, 12 seeds): the sigma predicted from the reference image
    alone, ``static_repeat_covariance_px2`` (2 C_ref: the target sampled at whole pixels), against each point's
    scatter over the seeds: std(error / sigma) in [0.9, 1.1] and 95 % coverage in [0.93, 0.97] for u and v."""
    from measurement.uncertainty.match import static_repeat_covariance_px2
    from measurement.uncertainty.stereo import sigmas

    reference, _ = fourier_shifted_pair((200, 200), speckle_px, (0.0, 0.0), seed=1, mean_grey=160.0, std_grey=25)
    settings = DICSettings(subset_size=subset, step=10, order=order)
    model = NoiseModel(read_grey, read_grey, None, "given")
    errors, predicted = [], []
    for s in range(SEEDS):
        ref = apply_sensor_noise(reference, read_noise_grey=read_grey, bit_depth=None, seed=2 * s)
        static = apply_sensor_noise(reference, read_noise_grey=read_grey, bit_depth=None, seed=2 * s + 1)
        result = correlate(ref, static, settings, roi=ROI)
        subsets = reference_subsets(ref, result.x, result.y, subset, order, model)
        errors.append(np.column_stack([result.u, result.v]))
        predicted.append(sigmas(static_repeat_covariance_px2(subsets.cov_uv_reference)))
    errors, predicted = np.array(errors), np.array(predicted)
    keep = np.all(np.isfinite(errors), axis=(0, 2)) & np.all(np.isfinite(predicted), axis=(0, 2))
    n = errors.shape[0]
    # about each point's own mean over the seeds, as above (a zero shift has no interpolation bias, but the claim
    # is on the random part)
    z = (errors - errors.mean(axis=0))[:, keep] * np.sqrt(n / (n - 1)) / predicted[:, keep]
    spread = z.std(axis=(0, 1))
    coverage = np.mean(np.abs(z) < 1.959964, axis=(0, 1))
    print(f"static repeat, speckle {speckle_px} px, noise {read_grey} grey, order {order}, subset {subset}: std(z) "
          f"{spread.round(3)}, 95 % coverage {coverage.round(3)} over {z.shape[1]} points x {z.shape[0]} draws")
    assert np.all((spread > 0.9) & (spread < 1.1))
    assert np.all((coverage > 0.93) & (coverage < 0.97))


def test_static_repeat_covariance_px2_refuses_another_shape():
    from measurement.uncertainty.match import static_repeat_covariance_px2

    with pytest.raises(ValueError, match=r"cov_reference_px2 must have shape \(N, 2, 2\), got \(4, 3, 3\)"):
        static_repeat_covariance_px2(np.zeros((4, 3, 3)))


def test_a_saturated_region_gets_no_sigma_and_says_why():
    """Pixels clipped at the sensor's ceiling carry no noise and no gradient: subsets more than 2 % clipped get
    NaN sigma and the 'saturated' flag; subsets without a clipped pixel keep theirs."""
    from measurement.uncertainty.match import FLAG_SATURATED

    reference, moved = fourier_shifted_pair((200, 200), 4.0, SHIFT, seed=1, mean_grey=160.0, std_grey=25)
    ref = apply_sensor_noise(reference, read_noise_grey=2.0, bit_depth=None, seed=1)
    mov = apply_sensor_noise(moved, read_noise_grey=2.0, bit_depth=None, seed=2)
    ceiling = 230.0                                   # the left half is 80 grey brighter and saturates
    ref[:, :100] += 80.0
    mov[:, :100] += 80.0
    ref, mov = np.minimum(ref, ceiling), np.minimum(mov, ceiling)
    result = correlate(ref, mov, DICSettings(subset_size=21, step=10), roi=ROI,
                       initial_parameters=lambda x, y: (0 * x + SHIFT[0], 0 * y + SHIFT[1]))
    unc = dic_uncertainty(ref, result, NoiseModel(2.0, 2.0, None, "given"))
    at = np.array([np.mean(ref[y - 10:y + 11, x - 10:x + 11] == ceiling) for x, y in zip(result.x, result.y)])
    assert (at > 0.02).sum() >= 10 and (at == 0).sum() >= 10
    assert np.all(unc.flag[(at > 0.02) & result.converged] == FLAG_SATURATED)
    assert np.all(np.isnan(unc.sigma_u_px[at > 0.02]))
    assert np.all(np.isfinite(unc.sigma_u_px[(at == 0) & result.converged]))
