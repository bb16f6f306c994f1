"""Planar (2-D DIC) classes of the uncertainty proof: one factor at a time around a centre class.

Each class renders an exact Gaussian-blob speckle (:func:`scenes.image_pairs.gaussian_speckle.gaussian_speckle`) and its exact
deformed image, then ``draws`` times adds fresh 8-bit sensor noise (read noise + quantisation) to both and to a
second, static copy of the reference. The instrument sees only the images: it correlates the pair, measures the
noise from the static pair (:func:`measurement.speckle_quality.noise_from_static_pair`, as a careful user would)
and reports each point's sigma (:func:`measurement.uncertainty.match.dic_uncertainty`).

Classes: the centre (4 px speckle, 2 grey, subset 41, first order, a 0.3 / 0.45 px translation), then read noise
0.5 and 5 grey, subset 21 and 65, speckle 2.5 and 8 px, second order, and a strain gradient that the first-order
shape function cannot follow (a quadratic field, 0.5 % strain change over the subset) with both orders.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .coverage import coverage_figures, random_deviation, verdict


@dataclass(frozen=True)
class PlanarClass:
    """One 2-D scenario class (module notes)."""

    name: str
    speckle_px: float = 4.0
    read_noise_grey: float = 2.0
    subset_px: int = 41
    order: int = 1
    field: str = "translation"       # or "quadratic"


PLANAR_CLASSES = (
    PlanarClass("centre"),
    PlanarClass("noise 0.5 grey", read_noise_grey=0.5),
    PlanarClass("noise 5 grey", read_noise_grey=5.0),
    PlanarClass("subset 21 px", subset_px=21),
    PlanarClass("subset 65 px", subset_px=65),
    PlanarClass("speckle 2.5 px", speckle_px=2.5),
    PlanarClass("speckle 8 px", speckle_px=8.0),
    PlanarClass("second order", order=2),
    PlanarClass("strain gradient, first order", field="quadratic"),
    PlanarClass("strain gradient, second order", field="quadratic", order=2),
)


def _field(kind: str, size: int):
    from scenes.image_pairs.analytic_fields import QuadraticField, Translation

    if kind == "translation":
        return Translation(0.3, 0.45)
    # du/dx changes by 2 a per px: 2 a x 41 px = 0.5 % over a 41 px subset
    a = 0.005 / (2 * 41)
    return QuadraticField((a, 0.0, 0.0), (0.0, 0.0, a), centre_xy_px=(size / 2, size / 2))


def run_planar_class(cls: PlanarClass, *, draws: int = 12, seed: int = 0, size: int = 256) -> dict:
    """Measure ``draws`` noisy pairs of the class and score the sigma (module notes).

    Returns the coverage figures (:func:`workbench.experiments.uncertainty.coverage.coverage_figures`, components
    u and v), the flagged fraction, the median sigma and noise, the RMS of the total error against the truth, the
    verdict against the goals, and the pooled z values (``"z"``, for the histograms).
    """
    from measurement.dic import DICSettings, correlate
    from measurement.speckle_quality import noise_from_static_pair
    from measurement.uncertainty.match import FLAG_NONE, dic_uncertainty
    from scenes.sensor.noise import SensorNoise
    from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size

    shape = (size, size)
    pattern = gaussian_speckle(extent_for_shape(shape, margin_px=16.0), radius_for_speckle_size(cls.speckle_px), 0.5,
                               seed, mean_grey=128.0, std_grey=30.0)
    field = _field(cls.field, size)
    reference = pattern.render_reference(shape)
    deformed = pattern.render_deformed(shape, field)
    margin = cls.subset_px // 2 + 8
    settings = DICSettings(subset_size=cls.subset_px, step=max(8, cls.subset_px // 4), order=cls.order)
    noise = SensorNoise(read_noise_grey=cls.read_noise_grey, bit_depth=8)
    measured, sigmas, flags, noise_sigma, misfits = [], [], [], [], []
    truth = None
    for d in range(draws):
        ref = noise.apply(reference, seed=seed * 1000 + 3 * d)
        static = noise.apply(reference, seed=seed * 1000 + 3 * d + 1)
        dfm = noise.apply(deformed, seed=seed * 1000 + 3 * d + 2)
        result = correlate(ref, dfm, settings, roi=(margin, margin, size - margin, size - margin))
        model = noise_from_static_pair(ref, static)
        unc = dic_uncertainty(ref, result, model, target=dfm, bias=True)
        if truth is None:
            truth = np.column_stack(field(result.x.astype(float), result.y.astype(float)))
        measured.append(np.column_stack([result.u, result.v]))
        sigmas.append(np.column_stack([unc.sigma_u_px, unc.sigma_v_px]))
        flags.append(unc.flag)
        misfits.append(unc.misfit_bias_px)
        noise_sigma.append(model.sigma_grey)
    values = np.array(measured)
    sigma = np.array(sigmas)
    flag = np.array(flags)
    trusted = np.all(flag == FLAG_NONE, axis=0)
    measured_points = np.all(np.isfinite(values[..., 0]), axis=0)
    flagged_fraction = float(np.count_nonzero(measured_points & ~trusted) / max(1, measured_points.sum()))
    deviation = random_deviation(values)
    keep = trusted & measured_points
    figures = coverage_figures(deviation[:, keep], sigma[:, keep], ("u", "v"))
    error = values[:, keep] - truth[keep]
    bias = error.mean(axis=0)
    # the shape-function misfit the instrument estimates from each draw's field, averaged like the bias
    misfit = np.nanmean(np.array(misfits)[:, keep], axis=0)
    z = (deviation[:, keep] / sigma[:, keep]).reshape(-1, 2)
    return {"class": cls.name, "kind": "planar", "settings": vars(cls) | {"draws": draws, "size_px": size},
            "components": figures, "flagged_fraction": flagged_fraction,
            "median_sigma": [float(np.nanmedian(sigma[:, keep, c])) for c in range(2)], "unit": "px",
            "noise_grey": float(np.mean(noise_sigma)),
            "noise_true_grey": float(math.hypot(cls.read_noise_grey, 12 ** -0.5)),
            "total_rmse": [float(np.sqrt(np.nanmean(error[..., c] ** 2))) for c in range(2)],
            "bias_rms": [float(np.sqrt(np.nanmean(bias[:, c] ** 2))) for c in range(2)],
            "misfit_rms": [float(np.sqrt(np.nanmean(misfit[:, c] ** 2))) for c in range(2)],
            "bias_rms_after_misfit": [float(np.sqrt(np.nanmean((bias[:, c] - misfit[:, c]) ** 2))) for c in range(2)],
            "verdict": verdict(figures, flagged_fraction), "z": z[np.all(np.isfinite(z), axis=1)]}
