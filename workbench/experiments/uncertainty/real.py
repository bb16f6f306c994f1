"""Real static pairs: does the instrument's sigma cover what a real camera's "static" pair measures?

The truth of a static pair is zero motion. Real pairs are rarely exactly still: DICe's StaticB exposures drift by a
few thousandths of a pixel as a whole (0.016 px after five exposures), which is motion of the coupon or the camera
common to every point, not a per-point error. A rigid motion of a plane appears to one camera as a near-affine
field, so both figures are given: the coverage of zero (the raw claim), and the coverage after the pair's common
motion -- an affine field u = a + b x + c y fitted over the points -- is removed (the random part the sigma
describes).

The sets are DICe's regression images (BSD 3-Clause, NTESS/Sandia), fetched by ``scripts/fetch_twin_data.sh`` into
``data/twin``; the instrument fits the noise to the match residuals (its default), and the static-pair noise
(:func:`measurement.speckle_quality.noise_from_static_pair`, the pair's mean motion undone) is shown beside.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .coverage import Z95

#: name -> (what, reference, static, ROI (x0, y0, x1, y1) or None, subset px, step px)
REAL_SETS = {
    "staticb_cam0_0to1": ("DICe StaticB, camera 0, exposures 0 -> 1", "staticb/img_0000_0.tif",
                          "staticb/img_0001_0.tif", (160, 300, 1100, 540), 27, 8),
    "staticb_cam1_0to1": ("DICe StaticB, camera 1, exposures 0 -> 1", "staticb/img_0000_1.tif",
                          "staticb/img_0001_1.tif", (160, 300, 1100, 540), 27, 8),
    "staticb_cam0_0to5": ("DICe StaticB, camera 0, exposures 0 -> 5", "staticb/img_0000_0.tif",
                          "staticb/img_0005_0.tif", (160, 300, 1100, 540), 27, 8),
    "staticb_cam1_0to3": ("DICe StaticB, camera 1, exposures 0 -> 3", "staticb/img_0000_1.tif",
                          "staticb/img_0003_1.tif", (160, 300, 1100, 540), 41, 8),
    "mechanism": ("DICe simple_tracking: the static wood-panel background, frames 4870 -> 4871 (natural texture)",
                  "mechanism/mechanism_4870.tif", "mechanism/mechanism_4871.tif", (5, 10, 190, 470), 27, 8),
}


def static_pair_coverage(reference: np.ndarray, static: np.ndarray, *, roi=None, subset_px: int = 27,
                         step_px: int = 8) -> dict:
    """Coverage of zero motion by the instrument's sigma on one static pair (module notes).

    Returns per noise source ("match residuals", "static pair"): per component u, v the std(z) and the 68 % and
    95 % coverage of zero and of the common-motion-free field, the flagged fraction, the mean motion and the noise.
    """
    from measurement.dic import DICSettings, correlate
    from measurement.speckle_quality import noise_from_static_pair
    from measurement.uncertainty.match import FLAG_NONE, dic_uncertainty

    result = correlate(reference, static, DICSettings(subset_size=subset_px, step=step_px), roi=roi)
    out = {"points": int(result.converged.sum())}
    motion = (float(np.nanmedian(result.u)), float(np.nanmedian(result.v)))
    for source in ("match residuals", "static pair"):
        model = None if source == "match residuals" else noise_from_static_pair(reference, static,
                                                                                motion_xy_px=motion)
        unc = dic_uncertainty(reference, result, model, target=static)
        ok = result.converged & (unc.flag == FLAG_NONE) & np.isfinite(unc.sigma_u_px)
        figures = {}
        design = np.column_stack([np.ones(int(ok.sum())), result.x[ok], result.y[ok]]).astype(float)
        for name, value, sigma in (("u", result.u, unc.sigma_u_px), ("v", result.v, unc.sigma_v_px)):
            raw = value[ok] / sigma[ok]
            common, *_ = np.linalg.lstsq(design, value[ok], rcond=None)
            centred = (value[ok] - design @ common) / sigma[ok]
            figures[name] = {"mean_px": float(value[ok].mean()), "median_sigma_px": float(np.median(sigma[ok])),
                             "coverage_95_of_zero": float(np.mean(np.abs(raw) < Z95)),
                             "std_z": float(np.std(centred)), "coverage_68": float(np.mean(np.abs(centred) < 1.0)),
                             "coverage_95": float(np.mean(np.abs(centred) < Z95))}
        out[source] = {"components": figures, "noise_grey": float(unc.noise_reference.sigma_grey),
                       "flagged_fraction": float(np.mean(unc.flag[result.converged] != FLAG_NONE))}
    return out


#: Exposures of StaticB camera 1 measured against exposure 0, further and further apart in time.
SERIES = [("staticb/img_0000_1.tif", f"staticb/img_000{k}_1.tif") for k in range(1, 6)]


def run_series(data_dir: Path, *, subset_px: int = 27, step_px: int = 8) -> list[dict]:
    """std(z) and 95 % coverage of the common-motion-free field for exposures 0 -> k of StaticB camera 1 (how the
    error beyond the noise grows with the time between the exposures); empty when the files are missing."""
    from measurement.image_io import read_grey

    rows = []
    for ref, static in SERIES:
        a, b = Path(data_dir) / ref, Path(data_dir) / static
        if not (a.is_file() and b.is_file()):
            return []
        f = static_pair_coverage(read_grey(a), read_grey(b), roi=REAL_SETS["staticb_cam1_0to1"][3],
                                 subset_px=subset_px, step_px=step_px)["match residuals"]["components"]
        rows.append({"pair": f"0 -> {static[-7]}", **{f"{c}_{k}": f[c][k] for c in f
                                                      for k in ("mean_px", "std_z", "coverage_95")}})
    return rows


def run_real(data_dir: Path) -> list[dict]:
    """Every set of :data:`REAL_SETS` found under ``data_dir`` (missing ones are skipped)."""
    from measurement.image_io import read_grey

    data_dir = Path(data_dir)
    rows = []
    for name, (what, ref, static, roi, subset, step) in REAL_SETS.items():
        a, b = data_dir / ref, data_dir / static
        if not (a.is_file() and b.is_file()):
            continue
        figures = static_pair_coverage(read_grey(a), read_grey(b), roi=roi, subset_px=subset, step_px=step)
        rows.append({"set": name, "what": what, "subset_px": subset, "step_px": step, **figures})
    return rows
