"""The shape-function misfit estimate (:mod:`measurement.uncertainty.misfit`) against an analytic solution and
against the error the match makes on an exact quadratic field.

Reference field: ``u = a dx^2``, ``v = a dy^2`` about the image centre (``scenes.image_pairs.analytic_fields.QuadraticField``,
an exact render of a Gaussian-blob speckle), ``a = 0.005 / 82`` per px: du/dx changes by 0.5 % over a 41 px subset.
A first-order 41 px subset's least-squares fit of ``a dx^2`` puts ``a (M^2 - 1) / 12 = 0.00854 px`` at its centre
for uniform texture (the mean of dx^2 over the subset): the analytic reference.
"""
import math

import numpy as np
import pytest

from measurement.dic import DICSettings, correlate
from measurement.dic.correlate import prepare_image
from measurement.speckle_quality import NoiseModel
from measurement.uncertainty.match import dic_uncertainty, reference_subsets
from measurement.uncertainty.misfit import field_derivatives, misfit_bias_px
from scenes.sensor.noise import SensorNoise
from scenes.image_pairs.analytic_fields import QuadraticField
from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size

SIZE = 256
SUBSET = 41
A = 0.005 / (2 * SUBSET)
FIELD = QuadraticField((A, 0.0, 0.0), (0.0, 0.0, A), centre_xy_px=(SIZE / 2, SIZE / 2))
CLOSED_FORM_PX = A * (SUBSET ** 2 - 1) / 12.0
NOISE = NoiseModel(2.0, 2.0, None, "given")


def _matches(order: int, draws: int):
    pattern = gaussian_speckle(extent_for_shape((SIZE, SIZE), margin_px=16.0), radius_for_speckle_size(4.0), 0.5, 0,
                               mean_grey=128.0, std_grey=30.0)
    reference = pattern.render_reference((SIZE, SIZE))
    deformed = pattern.render_deformed((SIZE, SIZE), FIELD)
    noise = SensorNoise(read_noise_grey=2.0, bit_depth=8)
    settings = DICSettings(subset_size=SUBSET, step=10, order=order)
    margin = SUBSET // 2 + 8
    out = []
    for d in range(draws):
        ref = noise.apply(reference, seed=3 * d)
        result = correlate(ref, noise.apply(deformed, seed=3 * d + 2), settings,
                           roi=(margin, margin, SIZE - margin, SIZE - margin))
        out.append((ref, result))
    return out


@pytest.fixture(scope="module")
def first_order():
    return _matches(1, 3)


def test_derivatives_of_the_measured_field_within_3_percent_of_the_analytic(first_order):
    """The curvature fitted to the measured (noisy, biased) field: u_xx = v_yy = 2 a within 3 % at the median point,
    the cross terms below 3 % of 2 a."""
    _, result = first_order[0]
    d = field_derivatives(result)
    med = np.nanmedian(d, axis=0)
    assert med[0, 0] == pytest.approx(2 * A, rel=0.03)
    assert med[1, 2] == pytest.approx(2 * A, rel=0.03)
    for c, t in ((0, 1), (0, 2), (1, 0), (1, 1)):
        assert abs(med[c, t]) < 0.03 * 2 * A, (c, t, med)


def test_projection_of_the_true_curvature_matches_the_closed_form_within_5_percent(first_order):
    """With the truth's derivatives the projection through each subset's gradients gives the closed form
    a (M^2 - 1) / 12 on average (within 5 %; the texture moves single subsets by a few per cent)."""
    ref, result = first_order[0]
    prepared = prepare_image(ref, "biquintic", True, "reference")
    subsets = reference_subsets(prepared, result.x, result.y, SUBSET, 1, NOISE)
    truth = np.zeros((result.x.size, 2, 3))
    truth[:, 0, 0] = truth[:, 1, 2] = 2 * A
    bias = misfit_bias_px(prepared, result, subsets.uv_rows, derivatives=truth)
    assert np.nanmean(bias[:, 0]) == pytest.approx(CLOSED_FORM_PX, rel=0.05)
    assert np.nanmean(bias[:, 1]) == pytest.approx(CLOSED_FORM_PX, rel=0.05)
    # and the other component is not moved by a curvature it does not have (within 5 % of the misfit)
    truth_u_only = truth.copy()
    truth_u_only[:, 1, 2] = 0.0
    bias_u = misfit_bias_px(prepared, result, subsets.uv_rows, derivatives=truth_u_only)
    assert abs(np.nanmean(bias_u[:, 1])) < 0.05 * CLOSED_FORM_PX


def test_the_estimate_from_the_images_alone_predicts_the_error_the_match_makes(first_order):
    """dic_uncertainty(bias=True) estimates the misfit from the match alone; its mean over the points equals the
    mean error of u and v against the truth (3 draws) within 5 % of the misfit -- an estimate of zero, what the
    instrument said before, is off by 100 %. Per point the error left after taking it off is at most the random
    part averaged over the draws plus the interpolation bias (RMS <= 0.004 px against 0.0085 px before)."""
    errors, estimates = [], []
    for ref, result in first_order:
        unc = dic_uncertainty(ref, result, NOISE, bias=True)
        truth = np.column_stack(FIELD(result.x.astype(float), result.y.astype(float)))
        errors.append(np.column_stack([result.u, result.v]) - truth)
        estimates.append(unc.misfit_bias_px)
        assert "misfit_bias_u_px" in unc.columns() and "misfit_bias_v_px" in unc.columns()
    error, estimate = np.nanmean(errors, axis=0), np.nanmean(estimates, axis=0)
    for c in range(2):
        assert abs(np.nanmean(error[:, c]) - np.nanmean(estimate[:, c])) < 0.05 * CLOSED_FORM_PX, c
        assert math.sqrt(np.nanmean(error[:, c] ** 2)) > 0.0075           # the misfit is there to be found
        assert math.sqrt(np.nanmean((error[:, c] - estimate[:, c]) ** 2)) <= 0.004, c


def test_second_order_subsets_have_no_misfit_on_a_quadratic_field():
    """A second-order shape function follows a quadratic field: the estimated misfit (from cubic terms of the
    measured field, which has none) is below a tenth of the first-order one everywhere it is measured."""
    (ref, result), = _matches(2, 1)
    unc = dic_uncertainty(ref, result, NOISE, bias=True)
    finite = np.isfinite(unc.misfit_bias_px)
    assert finite.mean() > 0.5
    assert np.all(np.abs(unc.misfit_bias_px[finite]) < 0.1 * CLOSED_FORM_PX)


def test_bad_shapes_are_refused(first_order):
    ref, result = first_order[0]
    prepared = prepare_image(ref, "biquintic", True, "reference")
    subsets = reference_subsets(prepared, result.x, result.y, SUBSET, 1, NOISE)
    with pytest.raises(ValueError, match=r"derivatives must have shape"):
        misfit_bias_px(prepared, result, subsets.uv_rows, derivatives=np.zeros((result.x.size, 2, 4)))
    with pytest.raises(ValueError, match=r"uv_rows must have shape"):
        misfit_bias_px(prepared, result, subsets.uv_rows[:, :, :4])
    with pytest.raises(ValueError, match=r"radius_points must be at least 1"):
        field_derivatives(result, radius_points=0)
