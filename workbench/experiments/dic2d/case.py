"""The ``dic2d`` study case: random and systematic error of 2-D subset DIC on an exactly translated pair.

Truth: a periodic Gaussian speckle image and its exact sub-pixel Fourier translation
(:func:`scenes.image_pairs.fourier_shift.fourier_shifted_pair`), with independent sensor noise in both images
(:mod:`scenes.sensor.noise`); stored in the dataset store under the hash of the scenario parts that make them, so a
sweep over instrument settings reuses them.

Metrics (px, over the points of interest): ``bias_px`` (mean error of u), ``random_error_px`` (std of the
error of u), ``rms_error_px``, ``valid_fraction``, and the theoretical floor ``predicted_error_px`` of Pan et
al. 2008 ("Study on subset size selection in digital image correlation for speckle patterns", Opt. Express
16, 7037), sqrt(2) sigma / sqrt(sum of f_x^2 over the subset) for noise sigma in both images, RMS over the
points. The floor is computed here from the exact image gradient (Fourier derivative of the noise-free,
band-limited reference), independently of the DIC engine; sigma includes the quantisation noise 1/sqrt(12)
grey of an integer bit depth and the mean shot noise.
"""
from __future__ import annotations

import io
import json
import time
from pathlib import Path

import numpy as np

from measurement.dic import DICSettings, correlate
from labio.atomic import atomic_write_bytes, atomic_write_text
from measurement.image_io import read_grey
from scenes.sensor.noise import apply_sensor_noise, to_image_dtype
from scenes.image_pairs.fourier_shift import fourier_shifted_pair
from workbench.manifest import complete_folder
from workbench.scenario import Instrument, Scenario

KIND = "dic2d"
#: Speckle (autocorrelation) size when the scenario leaves it open, px.
DEFAULT_SPECKLE_PX = 4.0
#: Grey std of the default 2-D pattern (mean 128); ``speckle.contrast`` scales it.
PATTERN_STD_GREY = 30.0

#: The metrics this case returns, with their units and the floor each one is compared with in plots.
METRICS = {"bias_px": "mean error of u (px)", "random_error_px": "std of the error of u (px)",
           "rms_error_px": "RMS error of u (px)", "predicted_error_px": "Pan 2008 floor sqrt(2) sigma / sqrt(SSSIG) (px)",
           "ratio_to_floor": "random error / Pan 2008 floor",
           "shape_floor_px": "floor of the full estimator: sqrt(2 σ² [H⁻¹]_uu), shape function + ZNSSD (px)",
           "ratio_to_shape_floor": "random error / full-estimator floor",
           "valid_fraction": "fraction of points matched", "dic_s": "DIC time (s)", "points": "points matched",
           "independent_points": "points with non-overlapping subsets (the random error's sample)"}
FLOORS = {"random_error_px": ("predicted_error_px", "Pan 2008: √2 σ / √Σ f_x²")}


def _write_float_tiff(path: Path, image: np.ndarray) -> None:
    import tifffile

    buffer = io.BytesIO()
    tifffile.imwrite(buffer, np.ascontiguousarray(image, dtype=np.float32))
    atomic_write_bytes(path, buffer.getvalue())


def render_dataset(scenario: Scenario, folder: Path) -> None:
    """Write ``reference``/``deformed`` images, ``clean_reference.tif`` (noise-free) and ``truth.json``."""
    im, sp, r = scenario.image2d, scenario.speckle, scenario.render
    n = im.size_px
    size_px = DEFAULT_SPECKLE_PX if sp.size_px is None else sp.size_px
    clean_ref, clean_def = fourier_shifted_pair((n, n), size_px, (im.shift_x_px, im.shift_y_px), seed=scenario.seed,
                                                density=sp.density, std_grey=PATTERN_STD_GREY * sp.contrast)
    bit_depth = r.bit_depth or None
    if r.electrons_per_grey is not None:
        # shot noise needs a signal >= 0: the band-limited pattern rings slightly below 0 on ~0.1 % of the pixels
        clean_ref, clean_def = np.maximum(clean_ref, 0.0), np.maximum(clean_def, 0.0)
    noisy = [apply_sensor_noise(img, read_noise_grey=r.read_noise_grey, electrons_per_grey=r.electrons_per_grey,
                                bit_depth=bit_depth, seed=1000 * scenario.seed + 17 + k)
             for k, img in enumerate((clean_ref, clean_def))]
    ext = "tif" if bit_depth is None else "png"
    names = [f"reference.{ext}", f"deformed.{ext}"]
    for name, img in zip(names, noisy):
        if bit_depth is None:
            _write_float_tiff(folder / name, img)
        else:
            from labio.atomic import atomic_write_image
            atomic_write_image(folder / name, to_image_dtype(img, bit_depth))
    _write_float_tiff(folder / "clean_reference.tif", clean_ref)
    truth = {"about": "2-D DIC pair: deformed(x, y) = reference(x - shift_x, y - shift_y) exactly (Fourier shift of "
                      "a periodic band-limited pattern); independent sensor noise in both images.",
             "shift_xy_px": [im.shift_x_px, im.shift_y_px], "size_px": n, "speckle_size_px": size_px,
             "read_noise_grey": r.read_noise_grey, "electrons_per_grey": r.electrons_per_grey,
             "bit_depth": r.bit_depth, "files": {"reference": names[0], "deformed": names[1],
                                                  "clean_reference": "clean_reference.tif"}}
    atomic_write_text(folder / "truth.json", json.dumps(truth, indent=1))
    complete_folder(folder, KIND, names + ["clean_reference.tif", "truth.json"], {"shift_xy_px": truth["shift_xy_px"]})


def _exact_gradient_x(image: np.ndarray) -> np.ndarray:
    """d image / dx of a periodic band-limited image (Fourier derivative), same shape."""
    kx = 2j * np.pi * np.fft.fftfreq(image.shape[1])
    spectrum = np.fft.fft(image, axis=1)
    if image.shape[1] % 2 == 0:
        spectrum[:, image.shape[1] // 2] = 0.0      # the Nyquist term has no odd derivative
    return np.real(np.fft.ifft(spectrum * kx[None, :], axis=1))


def image_noise_sigma_grey(scenario: Scenario, clean_image: np.ndarray) -> float:
    """RMS per-pixel noise std (grey) of one image: read, shot and quantisation noise
    (:func:`scenes.sensor.noise.noise_sigma_grey`, the prediction of the noise the image was given)."""
    from scenes.sensor.noise import noise_sigma_grey

    r = scenario.render
    sigma = noise_sigma_grey(np.maximum(clean_image, 0.0), r.read_noise_grey, r.electrons_per_grey,
                             r.bit_depth or None)
    return float(np.sqrt(np.mean(sigma ** 2)))


def pan_floor_px(clean_reference: np.ndarray, x: np.ndarray, y: np.ndarray, subset_px: int, sigma_grey: float) -> np.ndarray:
    """sqrt(2) sigma / sqrt(SSSIG_x) at each point (x, y) for square subsets of ``subset_px`` (Pan 2008)."""
    fx2 = _exact_gradient_x(clean_reference) ** 2
    integral = np.pad(np.cumsum(np.cumsum(fx2, 0), 1), ((1, 0), (1, 0)))
    h = subset_px // 2
    x0, x1, y0, y1 = x - h, x + h + 1, y - h, y + h + 1
    sssig = integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]
    return np.sqrt(2.0) * sigma_grey / np.sqrt(sssig)


def _exact_gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d/dx, d/dy) of a periodic band-limited image (Fourier derivatives)."""
    return _exact_gradient_x(image), _exact_gradient_x(image.T).T


def shape_function_floor_px(clean_reference: np.ndarray, x: np.ndarray, y: np.ndarray, subset_px: int, order: int,
                            sigma_grey: float) -> np.ndarray:
    """Noise floor of u at each point for the full estimator: std = sqrt(2 sigma^2 [H^-1]_uu).

    H = J^T J with one row of J per subset pixel: the exact gradient times the derivatives of the warp of
    ``order`` (1: 6 parameters, 2: 12) with respect to its parameters, plus the two nuisance parameters of the
    zero-normalised criterion (grey offset and gain: columns 1 and f). For a translation-only warp (zero
    order) it reduces to Pan 2008's sqrt(2) sigma / sqrt(SSSIG); a first-order warp adds little, a second-order
    warp ~1.8x on a uniform speckle (its quadratic terms correlate with the constant one). First-order
    (small-noise) theory: it ignores the noise of the reference image's gradient.
    """
    fx, fy = _exact_gradients(clean_reference)
    h = subset_px // 2
    dy, dx = np.mgrid[-h:h + 1, -h:h + 1]
    dx, dy = dx.ravel().astype(float), dy.ravel().astype(float)
    terms = [np.ones_like(dx), dx, dy]
    if order == 2:
        terms += [0.5 * dx * dx, dx * dy, 0.5 * dy * dy]
    out = np.empty(len(x))
    for i, (xi, yi) in enumerate(zip(x, y)):
        window = (slice(yi - h, yi + h + 1), slice(xi - h, xi + h + 1))
        gx, gy = fx[window].ravel(), fy[window].ravel()
        f = clean_reference[window].ravel()
        J = np.column_stack([gx * t for t in terms] + [gy * t for t in terms] + [np.ones_like(f), f - f.mean()])
        cov = np.linalg.inv(J.T @ J)
        out[i] = np.sqrt(2.0 * cov[0, 0]) * sigma_grey
    return out


#: Columns of a case's per-point file (:func:`write_points`).
POINT_COLUMNS = ("x", "y", "u", "v", "u_true", "v_true", "error_u", "error_v", "zncc", "iterations", "status",
                 "status_name", "independent")


def write_points(path: Path, result, shift_xy_px, independent: np.ndarray) -> Path:
    """One row per point of interest: position (px, integer pixel centres), measured u, v, the exact imposed
    translation, the error, ZNCC, IC-GN iterations, status (a failed point keeps NaN and says why) and whether
    the point belongs to the non-overlapping sub-grid the random error is taken over. Written atomically."""
    import csv

    from measurement.dic import Status
    from labio.atomic import atomic_writer

    fmt = lambda v: "nan" if not np.isfinite(v) else f"{v:.9g}"  # noqa: E731
    sx, sy = (float(v) for v in shift_xy_px)
    with atomic_writer(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(POINT_COLUMNS)
        for k in range(result.x.size):
            writer.writerow([int(result.x[k]), int(result.y[k]), fmt(result.u[k]), fmt(result.v[k]), fmt(sx), fmt(sy),
                             fmt(result.u[k] - sx), fmt(result.v[k] - sy), fmt(result.zncc[k]),
                             int(result.iterations[k]), int(result.status[k]), Status(int(result.status[k])).name.lower(),
                             int(bool(independent[k]))])
    return path


def measure(scenario: Scenario, instrument: Instrument, folder: Path, points_path: Path | None = None) -> dict:
    """Run the instrument on the stored pair and score u against the imposed shift; ``points_path``: also write
    the per-point file there (:func:`write_points`)."""
    truth = json.loads((folder / "truth.json").read_text())
    reference = read_grey(folder / truth["files"]["reference"])
    deformed = read_grey(folder / truth["files"]["deformed"])
    settings = DICSettings(subset_size=instrument.subset_px, step=instrument.step_px, order=instrument.shape_order,
                           interpolation=instrument.interpolation, lowpass_sigma_px=instrument.prefilter_sigma_px,
                           tolerance_px=1e-4)
    check(scenario, instrument)
    n = truth["size_px"]
    margin = instrument.subset_px // 2 + 8
    sx, sy = truth["shift_xy_px"]
    start = time.perf_counter()
    result = correlate(reference, deformed, settings, roi=(margin, margin, n - 1 - margin, n - 1 - margin),
                       initial_parameters=lambda x, y: (0.0 * x + sx, 0.0 * y + sy))
    seconds = time.perf_counter() - start
    # errors of overlapping subsets are correlated: the random error is the std over a sub-grid of points whose
    # subsets do not overlap (independent samples), the bias the mean over every point
    stride = -(-instrument.subset_px // instrument.step_px)
    independent = (result.grid_index[:, 0] % stride == 0) & (result.grid_index[:, 1] % stride == 0)
    ok = np.isfinite(result.u)
    sel = ok & independent
    error = result.u - sx
    clean = read_grey(folder / truth["files"]["clean_reference"])
    sigma = image_noise_sigma_grey(scenario, clean)
    pan = pan_floor_px(clean, result.x[sel], result.y[sel], instrument.subset_px, sigma)
    full = shape_function_floor_px(clean, result.x[sel], result.y[sel], instrument.subset_px, instrument.shape_order,
                                   sigma)
    predicted = float(np.sqrt(np.mean(pan ** 2)))
    predicted_full = float(np.sqrt(np.mean(full ** 2)))
    random = float(np.std(error[sel]))
    if points_path is not None:
        write_points(points_path, result, (sx, sy), independent)
    return {"bias_px": float(np.mean(error[ok])), "random_error_px": random,
            "rms_error_px": float(np.sqrt(np.mean(error[ok] ** 2))), "predicted_error_px": predicted,
            "ratio_to_floor": random / predicted if predicted > 0 else float("nan"),
            "shape_floor_px": predicted_full,
            "ratio_to_shape_floor": random / predicted_full if predicted_full > 0 else float("nan"),
            "valid_fraction": float(ok.mean()), "dic_s": seconds, "points": int(ok.sum()),
            "independent_points": int(sel.sum())}


def summary_lines(ds) -> list[str]:
    """The study's verdict on the theory: measured random error (RMS over the seeds) over each floor."""
    out = []
    rms = lambda da: np.sqrt((da ** 2).mean("repeat"))  # noqa: E731 - pooled over the seeds
    for floor, name in (("predicted_error_px", "Pan 2008 (sqrt(2) sigma / sqrt(SSSIG))"),
                        ("shape_floor_px", "the full estimator (shape function + ZNSSD offset/gain)")):
        if "random_error_px" not in ds or floor not in ds:
            continue
        ratio = (rms(ds["random_error_px"]) / rms(ds[floor])).values.ravel()
        ratio = ratio[np.isfinite(ratio)]
        if ratio.size:
            inside = int(np.sum(np.abs(ratio - 1.0) <= 0.10))
            out.append(f"random error / {name}: {ratio.min():.3f} to {ratio.max():.3f}; within 10 % at {inside} of "
                       f"{ratio.size} grid points")
    return out


def check(scenario: Scenario, instrument: Instrument | None = None) -> None:
    """Refuse what this experiment cannot do (called for every case before a study starts)."""
    if instrument is not None and scenario.image2d.size_px - 2 * (instrument.subset_px // 2 + 8) < 1:
        raise ValueError(f"scenario.image2d.size_px = {scenario.image2d.size_px} is too small for "
                         f"instrument.subset_px = {instrument.subset_px}")


def run(scenario: Scenario, instrument: Instrument, store, points_path: Path | None = None) -> dict:
    """Study entry point: the stored pair (rendered once per scenario content), measured and scored;
    ``points_path``: the per-point file of the case (u, v, truth, status per point)."""
    from workbench.scenario import dataset_parts

    key, content = dataset_parts(scenario)["images"]
    folder, reused = store.ensure(KIND, key, content, lambda f: render_dataset(scenario, f))
    metrics = measure(scenario, instrument, folder, points_path)
    out = {"metrics": metrics, "dims": {}, "coords": {}, "reused": {"images": reused}}
    if points_path is not None:
        out["points_file"] = Path(points_path).name
    return out
