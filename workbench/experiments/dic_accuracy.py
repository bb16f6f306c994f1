"""DIC accuracy report: interpolation bias vs sub-pixel shift, random error vs the noise floor, shape functions.

Images are exact (``scenes.synthetic_images``): Fourier-shifted speckle pairs for pure translations,
analytic Gaussian speckles sampled through a known displacement field for strain, quadratic fields and
rotations. Writes ``metrics.json``, ``bias.png`` and ``report.md``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from measurement.dic import DICSettings, correlate
from scenes.noise import apply_sensor_noise
from scenes.synthetic_images import (HomogeneousStrain, QuadraticField, Rotation, extent_for_shape,
                                     fourier_shifted_pair, gaussian_speckle)

SHIFTS_PX = np.round(np.arange(0.0, 1.01, 0.1), 10)
#: (label, speckle size px, interpolation, Gaussian pre-filter sigma px)
BIAS_CASES = (("biquintic, 4 px speckle", 4.0, "biquintic", 0.0),
              ("bicubic, 4 px speckle", 4.0, "bicubic", 0.0),
              ("biquintic, 2.5 px speckle", 2.5, "biquintic", 0.0),
              ("bicubic, 2.5 px speckle", 2.5, "bicubic", 0.0),
              ("biquintic, 2.5 px speckle, pre-filter 0.9 px", 2.5, "biquintic", 0.9))


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
    if progress:
        print("random error vs noise floor")
    noise = noise_ratio()
    if progress:
        print("shape functions")
    shapes = shape_function_cases()
    metrics = {"bias": [{**c.__dict__, "max_abs_px": c.max_abs_px} for c in curves], "noise": noise,
               "shape_functions": shapes}
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))

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
    fig.savefig(out_dir / "bias.png", dpi=130)
    plt.close(fig)

    lines = ["# DIC engine accuracy", "",
             "Exact images: Fourier-shifted Gaussian-speckle pairs (translations) and analytic Gaussian speckles "
             "sampled through known displacement fields. Speckle size is the autocorrelation size "
             "(`scenes.speckle.speckle_size_from_pattern`): 2.5 px means Gaussian blobs of sigma 0.72 px, whose "
             "spectrum is substantially aliased at 1 px sampling; 4 px means sigma 1.2 px.", "",
             "## Systematic error vs sub-pixel shift", "", "![bias](bias.png)", "",
             "| case | max abs bias (px) |", "|---|---|"]
    lines += [f"| {c.label} | {c.max_abs_px:.5f} |" for c in curves]
    lines += ["", "Goal: max |bias| <= 0.0005 px with biquintic (OpenCorr bicubic ~0.001 px, a plain quintic GN "
              "~0.00015 px on the issue's images).", "",
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
    (out_dir / "report.md").write_text("\n".join(lines))
    return metrics
