"""Calibration class of the uncertainty proof: the calibration term against many independent calibrations.

One rig (the paper's, Table 1, full scale) is calibrated ``n`` times, each time with its own board-pose seed
(12 views of the 11 x 8-corner, 5 mm checkerboard, :func:`workbench.poses.random_board_poses`), its own corner
noise (Gaussian, ``corner_noise_px``: 0.02 px is the reprojection RMS of the paper reproduction's rendered boards,
0.0199 / 0.0186 px) and, in a second class, its own board print error (every corner of the printed board off its
nominal place by a Gaussian ``print_error_mm`` in x and y, 1 µm; the calibration uses the nominal board, as a user
does). Each calibration
triangulates the same true pixel pairs (a 5 x 5 grid over +-15 mm on the plane the rig faces, and that grid moved
1 mm along the plane's normal) and propagates its own covariance to X and to U
(:mod:`measurement.uncertainty.calibration`). Scored: the spread of the errors over the calibrations (RMS about the
truth) against the median predicted sigma, per component (issue 36: within 20 %), and ``z = error / sigma`` of
each calibration (std, 95 % coverage).

The corners are the exact projections, not detected in rendered images: the class tests the covariance and its
propagation at the noise a rendered board gives, not the corner detector (whose error on rendered boards the paper
report measures). Each calibration is also run with the paper's single start (``multi_start=False``) to show what
the multi-start guard of :func:`measurement.calibration.stepwise.calibrate_camera` changes.
"""
from __future__ import annotations

import math
import time
import warnings

import numpy as np

#: Board-pose seeds start here (one per calibration).
FIRST_POSE_SEED = 100
N_VIEWS = 12
PATTERN = (11, 8)
SQUARE_MM = 5.0
TILT_GUESS_DEG = {"left": (0.0, -4.0), "right": (0.0, 4.0)}
#: Issue 36's goal for the calibration term: predicted and observed within 20 % per component.
GOAL = 0.20


def specimen_points(rig):
    """A 5 x 5 grid (+-15 mm) on the plane the rig faces, and that grid moved 1 mm along the plane's normal,
    (25, 3) mm each, left frame."""
    from workbench.rigs import facing_plane_world

    centre, normal = facing_plane_world(rig)
    e1 = np.cross([0.0, 1.0, 0.0], normal)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    g = np.linspace(-15.0, 15.0, 5)
    ref = np.array([centre + a * e1 + b * e2 for a in g for b in g])
    return ref, ref + normal


def true_pixels(rig, X_left_mm):
    """True pixel pairs (left (N, 2), right (N, 2)) of left-frame points (N, 3) mm."""
    return (rig.left.project(X_left_mm),
            rig.right.project(X_left_mm @ rig.R_right_from_left.T + rig.T_right_from_left_mm))


def _corners(rig, seed: int, corner_noise_px: float, print_error_mm: float):
    """Noisy corners of one calibration's 12 views, {side: (V, N, 2) px}, and the nominal board (N, 3) mm."""
    from measurement.calibration.detection import board_points_mm
    from scenes.surfaces.checkerboard import Checkerboard
    from workbench.experiments.calibration.views import board_outline_mm
    from workbench.poses import random_board_poses

    nominal = board_points_mm(PATTERN, SQUARE_MM)
    rng = np.random.default_rng([seed, 36])
    printed = nominal.copy()
    printed[:, :2] += rng.normal(0.0, print_error_mm, (len(nominal), 2))
    poses = random_board_poses(rig, board_outline_mm(Checkerboard()), N_VIEWS, seed)
    X = np.array([printed @ R.T + t for R, t in poses])
    out = {}
    for side in ("left", "right"):
        R, T = rig.pose(side)
        exact = rig.camera(side).project((X @ R.T + T).reshape(-1, 3)).reshape(N_VIEWS, len(nominal), 2)
        out[side] = exact + rng.normal(0.0, corner_noise_px, exact.shape)
    return out, nominal


def _one(rig, seed, corner_noise_px, print_error_mm, pixels, truth, multi_start):
    from measurement.calibration.stepwise import calibrate_stereo
    from measurement.stereo import triangulate
    from measurement.uncertainty.calibration import calibration_covariance_mm2, displacement_calibration_covariance_mm2

    corners, nominal = _corners(rig, seed, corner_noise_px, print_error_mm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = calibrate_stereo(corners["left"], corners["right"], nominal, (rig.left.width, rig.left.height),
                               tilt_guess_left_deg=TILT_GUESS_DEG["left"],
                               tilt_guess_right_deg=TILT_GUESS_DEG["right"], multi_start=multi_start)
    l0, r0, l1, r1 = pixels
    X_ref, X_def = truth
    args = (cal.left.camera, cal.right.camera, cal.R_right_from_left, cal.T_right_from_left_mm)
    Y0 = triangulate(*args, l0, r0).X_left_mm
    Y1 = triangulate(*args, l1, r1).X_left_mm
    diag = lambda c: np.sqrt(np.diagonal(c, axis1=1, axis2=2))  # noqa: E731
    return {"err_X": Y0 - X_ref, "err_U": (Y1 - Y0) - (X_def - X_ref),
            "sigma_X": diag(calibration_covariance_mm2(cal, l0, r0)),
            "sigma_U": diag(displacement_calibration_covariance_mm2(cal, l0, r0, l1, r1)),
            "rms_px": (cal.rms_px["left"], cal.rms_px["right"])}


def _score(runs: list[dict]) -> dict:
    out = {}
    for field, names in (("X", ("X", "Y", "Z")), ("U", ("U", "V", "W"))):
        err = np.array([r[f"err_{field}"] for r in runs])            # (n, P, 3) mm
        sig = np.array([r[f"sigma_{field}"] for r in runs])
        observed = np.sqrt(np.mean(err ** 2, axis=(0, 1)))
        predicted = np.sqrt(np.mean(np.median(sig, axis=0) ** 2, axis=0))
        z = err / sig
        for i, name in enumerate(names):
            zi = z[..., i].ravel()
            out[name] = {"observed_um": float(1e3 * observed[i]), "predicted_um": float(1e3 * predicted[i]),
                         "ratio": float(observed[i] / predicted[i]), "std_z": float(np.sqrt(np.mean(zi ** 2))),
                         "coverage_95": float(np.mean(np.abs(zi) <= 1.959964)),
                         "worst_calibration_z": float(np.max(np.sqrt(np.mean(z[..., i] ** 2, axis=1))))}
    return out


def run_calibration_class(*, calibrations: int = 20, corner_noise_px: float = 0.02, print_error_mm: float = 0.0,
                          single_start: bool = True, progress: bool = True) -> dict:
    """``calibrations`` independent calibrations of the paper's rig scored against the truth (module notes).

    Returns the class record: per component (X, Y, Z, U, V, W) the observed spread and the median predicted sigma
    (µm), their ratio, std and 95 % coverage of z; the same for the paper's single start when ``single_start``;
    the verdict (every ratio within :data:`GOAL`).
    """
    from workbench.rigs import paper_rig

    if calibrations < 2:
        raise ValueError(f"calibrations must be at least 2, got {calibrations}")
    rig = paper_rig(1.0)
    truth = specimen_points(rig)
    pixels = (*true_pixels(rig, truth[0]), *true_pixels(rig, truth[1]))
    start = time.perf_counter()
    multi, single = [], []
    for i in range(calibrations):
        seed = FIRST_POSE_SEED + i
        multi.append(_one(rig, seed, corner_noise_px, print_error_mm, pixels, truth, True))
        if single_start:
            single.append(_one(rig, seed, corner_noise_px, print_error_mm, pixels, truth, False))
        if progress:
            print(f"  calibration {i + 1}/{calibrations}", flush=True)
    components = _score(multi)
    name = "calibration (paper rig, board-pose seeds)" + (f", board print error {1e3 * print_error_mm:.1f} µm"
                                                          if print_error_mm > 0 else "")
    record = {"class": name, "kind": "calibration",
              "settings": {"calibrations": calibrations, "corner_noise_px": corner_noise_px,
                           "print_error_um": 1e3 * print_error_mm, "views": N_VIEWS,
                           "board": f"{PATTERN[0]} x {PATTERN[1]} corners, {SQUARE_MM} mm"},
              "components": components,
              "reprojection_rms_px": float(np.median([r["rms_px"] for r in multi])),
              "verdict": {"within_20_percent": all(abs(c["ratio"] - 1.0) <= GOAL for c in components.values())},
              "seconds": round(time.perf_counter() - start, 1)}
    if single_start:
        record["single_start"] = _score(single)
    return record


def calibration_lines(records: list[dict]) -> list[str]:
    """The report's section for the calibration classes."""
    lines = ["## Calibration term (systematic part)", ""]
    for record in records:
        lines += _class_lines(record)
    lines += ["X, Y, Z: a point's position (the calibration's whole error); U, V, W: a 1 mm move along the plane's "
              "normal (what a displacement inherits). The single start is the paper's procedure from the image "
              "centre: on some board-pose sets it stops in a second minimum of the tilt/principal-point valley, and "
              "those calibrations lie tens of sigma out; the instrument's multi-start guard keeps the lowest of five "
              "starts. A board print error is the same in every view: the calibration's covariance, made for "
              "independent corner errors, does not know it (the fitted residual grows, the parameters move along the "
              "valley far more than that residual says), so where the print error matters the calibration sigma is a "
              "lower bound.", ""]
    return lines


def _class_lines(record: dict) -> list[str]:
    s = record["settings"]
    lines = [f"### {record['class']}", "",
             f"The paper's rig calibrated {s['calibrations']} times, each with its own board poses ({s['views']} "
             f"views of a {s['board']} board), corner noise {s['corner_noise_px']} px (the rendered boards' "
             f"reprojection RMS) and board print error {s['print_error_um']:.1f} µm; the same true pixel pairs "
             "triangulated by each. Observed: the RMS of the errors about the truth over the calibrations; "
             "predicted: the median of the calibrations' own sigma (their linear covariance propagated). Goal: "
             f"within {100 * GOAL:.0f} %. Median reprojection RMS {record['reprojection_rms_px']:.4f} px.", "",
             "| comp. | observed (µm) | predicted (µm) | ratio | std(z) | 95 % coverage | worst calibration RMS z "
             "| paper's single start: ratio | std(z) |", "|---|---|---|---|---|---|---|---|---|"]
    single = record.get("single_start", {})
    for name, c in record["components"].items():
        o = single.get(name)
        ok = abs(c["ratio"] - 1.0) <= GOAL
        lines.append(f"| {name} | {c['observed_um']:.3g} | {c['predicted_um']:.3g} | "
                     f"{c['ratio']:.2f}{'' if ok else ' **missed**'} | {c['std_z']:.2f} | {c['coverage_95']:.3f} | "
                     f"{c['worst_calibration_z']:.1f} | {o['ratio']:.2f} | {o['std_z']:.2f} |" if o else
                     f"| {name} | {c['observed_um']:.3g} | {c['predicted_um']:.3g} | {c['ratio']:.2f} | "
                     f"{c['std_z']:.2f} | {c['coverage_95']:.3f} | {c['worst_calibration_z']:.1f} | – | – |")
    lines.append("")
    if not math.isfinite(record["reprojection_rms_px"]):
        lines += ["*No calibration converged.*", ""]
    return lines
