"""DIC accuracy report: interpolation bias vs sub-pixel shift, random error vs the noise floor, shape functions.

Images are exact (``scenes.image_pairs.gaussian_speckle``): Fourier-shifted speckle pairs for pure translations,
analytic Gaussian speckles sampled through a known displacement field for strain, quadratic fields and
rotations. Writes ``metrics.json``, ``bias.png`` and ``report.md``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from measurement.dic import DICSettings, correlate
from labio.atomic import atomic_write_text
from scenes.sensor.noise import apply_sensor_noise
from scenes.image_pairs.analytic_fields import HomogeneousStrain, QuadraticField, Rotation
from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size
from scenes.image_pairs.fourier_shift import fourier_shifted_pair
from workbench.manifest import save_figure

SHIFTS_PX = np.round(np.arange(0.0, 1.01, 0.1), 10)
#: (label, speckle size px, interpolation, Gaussian pre-filter sigma px)
BIAS_CASES = (("biquintic, 4 px speckle", 4.0, "biquintic", 0.0),
              ("bicubic, 4 px speckle", 4.0, "bicubic", 0.0),
              ("biquintic, 2.5 px speckle", 2.5, "biquintic", 0.0),
              ("bicubic, 2.5 px speckle", 2.5, "bicubic", 0.0),
              ("biquintic, 2.5 px speckle, pre-filter 0.9 px", 2.5, "biquintic", 0.9))


#: Speckle sizes (autocorrelation size, px) of the bias-vs-speckle-size sweep; 3.54 px = 2.5 px * sqrt(2) is the
#: pattern whose single blobs are 2.5 px wide at half maximum.
SIZE_SWEEP_PX = (2.5, 3.0, 3.54, 3.75, 4.0, 4.25, 4.5, 5.0)

#: External reference, not computed by this report: max |bias| of OpenCorr (github.com/vincentjzy/OpenCorr at
#: commit 500f447, FFT-CC + first-order IC-GN, bicubic B-spline, 4th-order finite-difference gradients, built
#: with g++ -O3 -march=native) on the same 512 x 512 Fourier-shifted pairs as the sweep (seed 1, subset 33,
#: step 12, float images), measured on 2026-11-23 beside this engine. It places the issue's "OpenCorr ~0.001 px
#: on such images" at 3.75-4.25 px on our size scale.
OPENCORR_BICUBIC_MAX_BIAS_PX = {2.5: 0.01517, 3.0: 0.00753, 3.54: 0.00223, 3.75: 0.00091, 4.0: 0.00075,
                                4.25: 0.00149, 4.5: 0.00226, 5.0: 0.00357}


def blob_fwhm_px(speckle_px: float) -> float:
    """Full width at half maximum of one Gaussian blob of the pattern with autocorrelation size ``speckle_px``."""
    return float(2.0 * radius_for_speckle_size(speckle_px) * np.sqrt(np.log(2.0)))


@dataclass
class BiasCurve:
    label: str
    speckle_px: float
    interpolation: str
    lowpass_sigma_px: float
    shifts_px: list
    bias_px: list

    @property
    def max_abs_px(self) -> float:
        return float(np.max(np.abs(self.bias_px)))


def bias_curve(speckle_px: float, interpolation: str, lowpass_sigma_px: float = 0.0, shape=(256, 256),
               subset_size: int = 33, seed: int = 1) -> np.ndarray:
    """Mean error of u over a grid of subsets vs shift (noise-free Fourier-shifted pairs), px."""
    errors = []
    for shift in SHIFTS_PX:
        reference, shifted = fourier_shifted_pair(shape, speckle_px, (shift, 0.0), seed=seed)
        settings = DICSettings(subset_size=subset_size, step=12, interpolation=interpolation, tolerance_px=1e-6,
                               lowpass_sigma_px=lowpass_sigma_px)
        margin = subset_size
        result = correlate(reference, shifted, settings, roi=(margin, margin, shape[1] - margin, shape[0] - margin),
                           initial_parameters=lambda x, y: (0.0 * x, 0.0 * y))
        errors.append(float(np.nanmean(result.u) - shift))
    return np.array(errors)


def bias_size_sweep(sizes_px=SIZE_SWEEP_PX, shape=(512, 512), progress: bool = False) -> list[dict]:
    """Max |bias| over the 0-1 px shifts vs speckle size, biquintic and bicubic (subset 33).

    Returns one dict per size: ``speckle_px``, ``blob_fwhm_px``, ``biquintic``, ``bicubic`` (px) and
    ``opencorr_bicubic_reference`` (px, None where not measured; a constant, see
    :data:`OPENCORR_BICUBIC_MAX_BIAS_PX`, valid for the default 512 x 512 pairs only).
    """
    rows = []
    for size in sizes_px:
        if progress:
            print(f"bias vs speckle size: {size} px")
        row = {"speckle_px": float(size), "blob_fwhm_px": blob_fwhm_px(size)}
        for interpolation in ("biquintic", "bicubic"):
            row[interpolation] = float(np.max(np.abs(bias_curve(size, interpolation, shape=shape))))
        row["opencorr_bicubic_reference"] = OPENCORR_BICUBIC_MAX_BIAS_PX.get(float(size)) \
            if tuple(shape) == (512, 512) else None
        rows.append(row)
    return rows


def noise_ratio(speckle_px: float = 4.0, sigma_grey: float = 2.0, draws: int = 8, seed: int = 10) -> dict:
    """std(u) under Gaussian noise in both images / sqrt(2) sigma / sqrt(SSSIG) (Pan 2008), per shift and overall."""
    settings = DICSettings(subset_size=33, step=33, tolerance_px=1e-4)
    roi = (20, 20, 492, 492)
    out, all_errors, all_predicted = {}, [], []
    for shift in (0.0, 0.25, 0.5):
        reference, shifted = fourier_shifted_pair((512, 512), speckle_px, (shift, 0.0), seed=seed)
        guess = lambda x, y: (0.0 * x + shift, 0.0 * y)  # noqa: E731
        clean = correlate(reference, shifted, settings, roi=roi, initial_parameters=guess)
        errors, predicted = [], []
        for k in range(draws):
            a = apply_sensor_noise(reference, read_noise_grey=sigma_grey, bit_depth=None, seed=100 + k)
            b = apply_sensor_noise(shifted, read_noise_grey=sigma_grey, bit_depth=None, seed=200 + k)
            result = correlate(a, b, settings, roi=roi, initial_parameters=guess)
            errors.append(result.u - clean.u)
            predicted.append(result.predicted_std_px(sigma_grey)[0])
        errors, predicted = np.concatenate(errors), np.concatenate(predicted)
        out[f"shift {shift:.2f} px"] = {"std_px": float(errors.std()),
                                        "theory_px": float(np.sqrt(np.mean(predicted ** 2))),
                                        "ratio": float(errors.std() / np.sqrt(np.mean(predicted ** 2))),
                                        "points": int(errors.size)}
        all_errors.append(errors)
        all_predicted.append(predicted)
    errors, predicted = np.concatenate(all_errors), np.concatenate(all_predicted)
    out["all"] = {"std_px": float(errors.std()), "theory_px": float(np.sqrt(np.mean(predicted ** 2))),
                  "ratio": float(errors.std() / np.sqrt(np.mean(predicted ** 2))), "points": int(errors.size)}
    return out


def _field_errors(result, field) -> dict:
    ok = result.converged
    u, v = field(result.x[ok].astype(float), result.y[ok].astype(float))
    gradient = field.gradient(result.x[ok].astype(float), result.y[ok].astype(float))
    p = result.parameters[ok]
    return {"points": int(result.x.size), "converged": int(ok.sum()),
            "max_abs_u_error_px": float(np.max(np.abs(p[:, 0] - u))),
            "max_abs_v_error_px": float(np.max(np.abs(p[:, 6] - v))),
            "mean_u_error_px": float(np.mean(p[:, 0] - u)),
            "max_abs_gradient_error": float(max(np.max(np.abs(p[:, 1] - gradient[0])),
                                                np.max(np.abs(p[:, 2] - gradient[1])),
                                                np.max(np.abs(p[:, 7] - gradient[2])),
                                                np.max(np.abs(p[:, 8] - gradient[3]))))}


def shape_function_cases(seed: int = 5) -> dict:
    """Strain 0.5 % and 2 %, a quadratic field and rotations, first and second order (noise-free)."""
    shape = (256, 256)
    pattern = gaussian_speckle(extent_for_shape(shape, margin_px=60), 1.8, seed=seed)
    reference = pattern.render_reference(shape)
    centre = (128.0, 128.0)
    a = 2e-4
    fields = {"strain 0.5 %": HomogeneousStrain(0.005, -0.0015, 0.0, centre_xy_px=centre),
              "strain 2 %": HomogeneousStrain(0.02, -0.006, 0.0, centre_xy_px=centre),
              "quadratic u = 2e-4 dx^2, v = 2e-4 dy^2": QuadraticField((a, 0.0, 0.0), (0.0, 0.0, a), centre),
              "rotation 10 deg": Rotation(10.0, centre),
              "rotation 30 deg": Rotation(30.0, centre)}
    out = {}
    for name, field in fields.items():
        deformed = pattern.render_deformed(shape, field)
        for order in (1, 2):
            result = correlate(reference, deformed, DICSettings(subset_size=41, step=17, order=order),
                               roi=(60, 60, 196, 196))
            out[f"{name}, order {order}"] = _field_errors(result, field)
    out["first-order undermatching expected for the quadratic field, px"] = a * 20 * 21 / 3.0
    return out


def reproduce_dic_accuracy(out_dir: str | Path, progress: bool = True) -> dict:
    """Run the accuracy cases and write metrics.json, bias.png and report.md into ``out_dir``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    curves = []
    for label, speckle, interpolation, sigma in BIAS_CASES:
        if progress:
            print(f"bias curve: {label}")
        bias = bias_curve(speckle, interpolation, sigma)
        curves.append(BiasCurve(label, speckle, interpolation, sigma, SHIFTS_PX.tolist(), bias.tolist()))
    sweep = bias_size_sweep(progress=progress)
    if progress:
        print("random error vs noise floor")
    noise = noise_ratio()
    if progress:
        print("shape functions")
    shapes = shape_function_cases()
    metrics = {"bias": [{**c.__dict__, "max_abs_px": c.max_abs_px} for c in curves], "bias_vs_speckle_size": sweep,
               "noise": noise, "shape_functions": shapes}
    atomic_write_text(out_dir / "metrics.json", json.dumps(metrics, indent=2))

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for c in curves:
        ax.plot(c.shifts_px, np.array(c.bias_px) * 1e3, marker="o", ms=3, label=f"{c.label} (max {c.max_abs_px * 1e3:.2f})")
    ax.axhspan(-0.5, 0.5, color="0.9", label="goal |bias| <= 0.5e-3 px")
    ax.set_xlabel("imposed sub-pixel shift (px)")
    ax.set_ylabel("mean error of u (1e-3 px)")
    ax.set_title("Interpolation bias (IC-GN 1st order, subset 33, noise-free)", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, out_dir / "bias.png", dpi=130)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 4.2))
    sizes = [row["speckle_px"] for row in sweep]
    ax.semilogy(sizes, [row["biquintic"] for row in sweep], "o-", label="this engine, biquintic")
    ax.semilogy(sizes, [row["bicubic"] for row in sweep], "s-", label="this engine, bicubic")
    reference = [(row["speckle_px"], row["opencorr_bicubic_reference"]) for row in sweep
                 if row["opencorr_bicubic_reference"] is not None]
    if reference:
        ax.semilogy(*zip(*reference), "^--", color="0.45",
                    label="OpenCorr 500f447, bicubic (measured 2026-11-23, not re-run)")
    ax.axhline(5e-4, color="k", lw=0.8, ls=":", label="goal 0.0005 px (biquintic)")
    ax.set_xlabel("speckle size: autocorrelation FWHM (px)")
    ax.set_ylabel("max |bias| over 0-1 px shifts (px)")
    ax.set_title("Interpolation bias vs speckle size (IC-GN 1st order, subset 33, noise-free)", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fwhm = [row["blob_fwhm_px"] for row in sweep]
    top = ax.secondary_xaxis("top", functions=(lambda s: np.interp(s, sizes, fwhm),
                                               lambda d: np.interp(d, fwhm, sizes)))
    top.set_xticks([d for d in np.arange(1.5, 4.01, 0.25) if min(fwhm) <= d <= max(fwhm)])
    top.set_xlabel("single-blob FWHM diameter (px)", fontsize=8)
    fig.tight_layout()
    save_figure(fig, out_dir / "bias_vs_speckle_size.png", dpi=130)
    plt.close(fig)

    lines = ["# DIC engine accuracy", "",
             "Exact images: Fourier-shifted Gaussian-speckle pairs (translations) and analytic Gaussian speckles "
             "sampled through known displacement fields. Speckle size is the autocorrelation size "
             "(`scenes.surfaces.speckle.speckle_size_from_pattern`, full width at half maximum of the autocorrelation): "
             "2.5 px means Gaussian blobs of sigma 0.72 px, whose spectrum is substantially aliased at 1 px "
             "sampling; 4 px means sigma 1.2 px.", "",
             "## Systematic error vs sub-pixel shift", "", "![bias](bias.png)", "",
             "| case | max abs bias (px) |", "|---|---|"]
    lines += [f"| {c.label} | {c.max_abs_px:.5f} |" for c in curves]
    lines += ["", "Goal: max |bias| <= 0.0005 px with biquintic (OpenCorr bicubic ~0.001 px, a plain quintic GN "
              "~0.00015 px on the issue's images).", "",
              "## Bias vs speckle size: which images are \"such images\"", "",
              "A speckle size alone does not fix the images: by the autocorrelation FWHM used here a pattern of "
              "Gaussian blobs reads sqrt(2) times its single-blob FWHM diameter, and other conventions (blob "
              "radius, 2 sigma) differ again. The issue pins its images down by OpenCorr's bias on them "
              "(~0.001 px, bicubic). OpenCorr, built from its source and run on the same pairs, reads that at "
              "3.75-4.25 px here; at 2.5 px (autocorrelation) it reads 0.015 px.", "",
              "![bias vs speckle size](bias_vs_speckle_size.png)", "",
              "| speckle size (autocorr. FWHM, px) | single-blob FWHM (px) | biquintic max abs bias (px) | "
              "bicubic (px) | OpenCorr bicubic, external reference (px) |", "|---|---|---|---|---|"]
    lines += [f"| {row['speckle_px']:.2f} | {row['blob_fwhm_px']:.2f} | {row['biquintic']:.5f} | "
              f"{row['bicubic']:.5f} | "
              + (f"{row['opencorr_bicubic_reference']:.5f}" if row['opencorr_bicubic_reference'] is not None else "-")
              + " |" for row in sweep]
    meeting = [row["speckle_px"] for row in sweep if row["biquintic"] <= 5e-4]
    filtered = [c for c in curves if c.lowpass_sigma_px > 0]
    if meeting:
        lines += ["", f"Biquintic meets the 0.0005 px goal from {min(meeting):.2f} px (autocorrelation) up, which "
                  "includes the sizes where OpenCorr reads ~0.001 px."
                  + (f" Finer patterns need the Gaussian pre-filter: {filtered[0].label}: "
                     f"{filtered[0].max_abs_px:.5f} px." if filtered else "")]
    lines += ["", "The OpenCorr column is a measurement made once beside this engine (see "
              "`OPENCORR_BICUBIC_MAX_BIAS_PX` in `workbench/experiments/dic2d/accuracy.py` for how); this report does "
              "not run OpenCorr. Its curve is not monotonic because its finite-difference reference gradients add "
              "an error of their own that grows with the speckle size.", "",
              "## Random error (Gaussian noise sigma 2 grey in both images, subset 33, 4 px speckle)", "",
              "| shift | std(u) px | theory sqrt(2) sigma / sqrt(SSSIG) px | ratio | points |", "|---|---|---|---|---|"]
    lines += [f"| {k} | {v['std_px']:.5f} | {v['theory_px']:.5f} | {v['ratio']:.3f} | {v['points']} |"
              for k, v in noise.items()]
    lines += ["", "Goal: ratio <= 1.05 (OpenCorr ~1.04).", "", "## Shape functions (noise-free, subset 41)", "",
              "| case | converged | max abs u error px | mean u error px | max abs gradient error |", "|---|---|---|---|---|"]
    lines += [f"| {k} | {v['converged']}/{v['points']} | {v['max_abs_u_error_px']:.5f} | {v['mean_u_error_px']:.5f} "
              f"| {v['max_abs_gradient_error']:.2e} |" for k, v in shapes.items() if isinstance(v, dict)]
    lines += ["", f"First-order undermatching expected on the quadratic field: "
              f"{shapes['first-order undermatching expected for the quadratic field, px']:.4f} px "
              "(a M (M + 1) / 3 at the subset centre).", ""]
    atomic_write_text(out_dir / "report.md", "\n".join(lines))
    return metrics
