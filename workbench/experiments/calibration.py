"""The paper's calibration protocol (§4.2, Table 1, Fig 5) on rendered views of the true rig.

30 calibration and 20 validation stereo views of the 12 x 9-square board are rendered (8-bit, Gaussian noise),
the instrument calibrates from the image files alone, and the result is scored against the truth:

* reprojection RMS per camera;
* 3D accuracy: the validation corners, triangulated with the calibrated rig from their *exact* projections,
  against their true 3D positions, before and after one rigid alignment common to all points (a calibration
  may define a slightly rotated left frame: a principal-point error is a frame rotation);
* projection agreement: the calibrated cameras project the aligned true points onto the true pixels;
* the paper's own check: plane fits of the 20 validation boards triangulated from *detected* corners;
* the same for the conventional ``pinhole`` model, which ignores the sensor tilt.
"""
from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from measurement.calibration.detection import detect_checkerboard
from measurement.calibration.images import calibrate_from_files, read_grey
from measurement.calibration.io import CalibratedRig, export_opencv_yaml, save_calibration
from measurement.camera import INTRINSIC_NAMES
from measurement.rigid import apply_rigid, fit_rigid
from measurement.stereo import fit_plane, triangulate
from scenes.noise import SensorNoise
from scenes.targets import Checkerboard
from workbench.experiments.checkerboard_views import board_outline_mm, write_checkerboard_dataset
from workbench.poses import random_board_poses
from workbench.rigs import StereoRig, paper_rig, paper_values

#: The datasheet tilt used for step 1 (a nominal adapter angle, deliberately not the true value).
DATASHEET_TILT_DEG = {"left": (0.0, -4.0), "right": (0.0, 4.0)}


def _as_rig(cal) -> CalibratedRig:
    return CalibratedRig(cal.model, cal.left.camera, cal.right.camera, cal.R_right_from_left, cal.T_right_from_left_mm)


def score_against_truth(rig_cal: CalibratedRig, truth_rig: StereoRig, val_points_left_mm: np.ndarray) -> dict:
    """3D and projection accuracy of a calibrated rig on exact projections of true points (left frame, mm)."""
    X_true = val_points_left_mm.reshape(-1, 3)
    R, T = truth_rig.pose("right")
    px_l = truth_rig.left.project(X_true)
    px_r = truth_rig.right.project(X_true @ R.T + T)
    tri = triangulate(rig_cal.left, rig_cal.right, rig_cal.R_right_from_left, rig_cal.T_right_from_left_mm, px_l, px_r)
    X_est = tri.X_left_mm
    err_unaligned = np.linalg.norm(X_est - X_true, axis=1)
    Ra, ta = fit_rigid(X_est, X_true)          # R X_est + t ~ X_true
    err_aligned = np.linalg.norm(apply_rigid(Ra, ta, X_est) - X_true, axis=1)
    X_in_cal = (X_true - ta) @ Ra                # true points expressed in the calibrated left frame
    pl = rig_cal.left.project(X_in_cal)
    pr = rig_cal.right.project(X_in_cal @ rig_cal.R_right_from_left.T + rig_cal.T_right_from_left_mm)
    proj = np.concatenate([pl - px_l, pr - px_r])
    rot_deg = float(np.degrees(np.linalg.norm(cv2.Rodrigues(Ra)[0])))
    return {"points": int(len(X_true)), "valid": int(tri.valid.sum()),
            "rms_3d_unaligned_um": float(1e3 * np.sqrt(np.nanmean(err_unaligned ** 2))),
            "rms_3d_aligned_um": float(1e3 * np.sqrt(np.nanmean(err_aligned ** 2))),
            "max_3d_aligned_um": float(1e3 * np.nanmax(err_aligned)),
            "alignment_rotation_deg": rot_deg, "alignment_translation_mm": float(np.linalg.norm(ta)),
            "projection_rms_px": float(np.sqrt(np.nanmean(np.sum(proj ** 2, axis=1))))}


def plane_fits_of_detected_boards(rig_cal: CalibratedRig, files_left, files_right) -> dict:
    """The paper's check: triangulate detected corners of each validation board, fit a plane, collect distances."""
    distances, per_board = [], []
    example = None
    for fl, fr in zip(files_left, files_right):
        cl, cr = detect_checkerboard(read_grey(fl)), detect_checkerboard(read_grey(fr))
        if cl is None or cr is None:
            warnings.warn(f"validation board not found in {fl if cl is None else fr}; skipped", stacklevel=2)
            continue
        tri = triangulate(rig_cal.left, rig_cal.right, rig_cal.R_right_from_left, rig_cal.T_right_from_left_mm, cl, cr)
        normal, d, dist = fit_plane(tri.X_left_mm)
        distances.append(dist)
        per_board.append(float(1e3 * np.sqrt(np.nanmean(dist ** 2))))
        if example is None:
            example = {"file_left": str(fl), "X_left_mm": tri.X_left_mm.tolist(), "distance_mm": dist.tolist(),
                       "normal": normal.tolist(), "d_mm": float(d)}
    if not distances:
        raise ValueError("no validation board was detected")
    all_d = np.concatenate(distances)
    return {"boards": len(distances), "rmse_um": float(1e3 * np.sqrt(np.nanmean(all_d ** 2))),
            "max_abs_um": float(1e3 * np.nanmax(np.abs(all_d))), "per_board_rmse_um": per_board, "example": example}


def reproduce_calibration(out_dir: Path, *, scale: float = 1.0, seed: int = 0, spp: int = 64, noise_grey: float = 1.0,
                          n_calibration: int = 30, n_validation: int = 20, models=("rmm", "pinhole"),
                          progress: bool = True) -> dict:
    """Render, calibrate, validate; writes images, calibration files, ``metrics.json`` and ``report.md``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rig = paper_rig(scale)
    board = Checkerboard()
    poses = random_board_poses(rig, board_outline_mm(board), n_calibration + n_validation, seed)
    t0 = time.perf_counter()
    truth = write_checkerboard_dataset(rig, out_dir / "images", n_calibration + n_validation, seed, spp=spp,
                                       board=board, noise=SensorNoise(read_noise_grey=noise_grey, bit_depth=8),
                                       progress=progress, poses=poses)
    t_render = time.perf_counter() - t0
    files = {side: [out_dir / "images" / im["file"] for im in truth["images"] if im["camera"] == side]
             for side in ("left", "right")}
    cal_files = {s: f[:n_calibration] for s, f in files.items()}
    val_files = {s: f[n_calibration:] for s, f in files.items()}
    val_points = np.array([im["points_cam_mm"] for im in truth["images"]
                           if im["camera"] == "left" and im["view"] >= n_calibration])
    metrics = {"scale": scale, "image_size_px": [rig.left.width, rig.left.height], "seed": seed, "spp": spp,
               "noise_grey": noise_grey, "calibration_views": n_calibration, "validation_views": n_validation,
               "render_s": round(t_render, 1), "datasheet_tilt_deg": DATASHEET_TILT_DEG,
               "truth": {s: rig.camera(s).intrinsics() for s in ("left", "right")}, "models": {}}
    for model in models:
        t0 = time.perf_counter()
        cal, pairs = calibrate_from_files(cal_files["left"], cal_files["right"], square_mm=board.square_mm,
                                          model=model, tilt_guess_left_deg=DATASHEET_TILT_DEG["left"],
                                          tilt_guess_right_deg=DATASHEET_TILT_DEG["right"], progress=progress)
        t_cal = time.perf_counter() - t0
        suffix = "" if model == "rmm" else f"_{model}"
        save_calibration(cal, out_dir / f"calibration{suffix}.json")
        export_opencv_yaml(cal, out_dir / f"calibration{suffix}.yaml")
        rig_cal = _as_rig(cal)
        m = {"calibration_s": round(t_cal, 1), "views_used": len(pairs.left_files), "dropped": pairs.dropped,
             "reprojection_rms_px": dict(cal.rms_px),
             "estimate": {s: getattr(cal, s).camera.intrinsics() for s in ("left", "right")},
             "sigma": {s: getattr(cal, s).sigma for s in ("left", "right")},
             "stereo": {"R_right_from_left": cal.R_right_from_left.tolist(),
                        "T_right_from_left_mm": cal.T_right_from_left_mm.tolist(), "sigma": cal.sigma_stereo},
             "steps": [[s[0], s[2]] for s in cal.steps],
             "validation_exact": score_against_truth(rig_cal, rig, val_points),
             "validation_plane_fit": plane_fits_of_detected_boards(rig_cal, val_files["left"], val_files["right"])}
        metrics["models"][model] = m
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=1))
    write_calibration_report(metrics, out_dir)
    return metrics


def write_calibration_report(metrics: dict, out_dir: Path) -> None:
    """``report.md`` with Table 1 side by side and the validation figures, plus ``plane_fit.png`` (Fig 5)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paper = paper_values()["table1_calibration"]
    protocol = paper_values()["calibration_protocol"]
    scale = metrics["scale"]
    rmm = metrics["models"].get("rmm") or next(iter(metrics["models"].values()))
    w, h = metrics["image_size_px"]
    lines = ["# Calibration: the paper's stepwise Scheimpflug stereo calibration on the rendered rig", "",
             f"{metrics['calibration_views']} calibration + {metrics['validation_views']} validation stereo views of "
             f"the 12 × 9-square, 5 mm board, {w} × {h} px (scale {scale}), {metrics['spp']} spp, 8-bit, "
             f"σ = {metrics['noise_grey']} grey level read noise. Step 1 tilt guess (datasheet): left "
             f"{tuple(metrics['datasheet_tilt_deg']['left'])}°, right {tuple(metrics['datasheet_tilt_deg']['right'])}°.",
             "", "## Table 1 side by side (model `rmm`)", ""]
    for side in ("left", "right"):
        lines += [f"**{side} camera**", "", "| parameter | truth | estimated ± σ | error / σ | paper |", "|---|---|---|---|---|"]
        for n in INTRINSIC_NAMES:
            t, e, s = metrics["truth"][side][n], rmm["estimate"][side][n], rmm["sigma"][side][n]
            key = n if n.endswith("_deg") or n.startswith(("k", "p")) else f"{n}_px"
            p = paper[side].get(key, float("nan"))
            if n in ("fx", "fy", "cx", "cy") and scale != 1:
                p = p * scale if n in ("fx", "fy") else (p + 0.5) * scale - 0.5
            ratio = (e - t) / s if s > 0 else float("nan")
            lines.append(f"| {n} | {t:.4f} | {e:.4f} ± {s:.4f} | {ratio:+.1f} | {p:.4f} |")
        lines.append("")
    lines += ["Tilt and principal point are nearly degenerate on planar targets: their σ is large and the estimates "
              "trade off against each other while the projection stays right (see the validation below).", "",
              "## Accuracy", "",
              "| model | reproj. RMS L / R [px] | 3D RMS unaligned [µm] | 3D RMS aligned [µm] | projection RMS [px] | "
              "plane-fit RMSE / max [µm] | time [s] |", "|---|---|---|---|---|---|---|"]
    for model, m in metrics["models"].items():
        v, pf = m["validation_exact"], m["validation_plane_fit"]
        lines.append(f"| {model} | {m['reprojection_rms_px']['left']:.4f} / {m['reprojection_rms_px']['right']:.4f} | "
                     f"{v['rms_3d_unaligned_um']:.2f} | {v['rms_3d_aligned_um']:.3f} | {v['projection_rms_px']:.4f} | "
                     f"{pf['rmse_um']:.2f} / {pf['max_abs_um']:.2f} | {m['calibration_s']} |")
    lines += ["", f"Paper (real images): reprojection {paper['left']['reprojection_error_px']} / "
              f"{paper['right']['reprojection_error_px']} px, plane-fit RMSE {1e3 * protocol['plane_fit_rmse_mm']:.1f} µm, "
              f"max {1e3 * protocol['plane_fit_max_deviation_mm']:.0f} µm.", "",
              "3D figures use the exact projections of the validation corners (what the calibration alone costs); "
              "the plane fits use corners detected in the noisy validation images (the paper's check).", "",
              "![plane fit](plane_fit.png)", ""]
    (Path(out_dir) / "report.md").write_text("\n".join(lines))
    ex = rmm["validation_plane_fit"]["example"]
    X, dist = np.array(ex["X_left_mm"]), 1e3 * np.array(ex["distance_mm"])
    fig = plt.figure(figsize=(11, 4.5), constrained_layout=True)
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.scatter(X[:, 0], X[:, 1], X[:, 2], c=dist, cmap="coolwarm", s=12)
    n, d = np.array(ex["normal"]), ex["d_mm"]
    gx, gy = np.meshgrid(np.linspace(X[:, 0].min(), X[:, 0].max(), 5), np.linspace(X[:, 1].min(), X[:, 1].max(), 5))
    ax.plot_surface(gx, gy, (d - n[0] * gx - n[1] * gy) / n[2], alpha=0.25, color="grey")
    ax.set_xlabel("X [mm]")
    ax.set_ylabel("Y [mm]")
    ax.set_zlabel("Z [mm]")
    ax.set_title("(a) reconstructed corners and fitted plane")
    ax2 = fig.add_subplot(1, 2, 2)
    grid = dist.reshape(8, 11)
    im = ax2.imshow(grid, cmap="coolwarm", vmin=-np.abs(grid).max(), vmax=np.abs(grid).max())
    ax2.set_title("(b) distance to the fitted plane [µm]")
    ax2.set_xlabel("corner column")
    ax2.set_ylabel("corner row")
    fig.colorbar(im, ax=ax2)
    fig.savefig(Path(out_dir) / "plane_fit.png", dpi=110)
    plt.close(fig)
