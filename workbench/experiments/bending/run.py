"""The paper's three-point bending test (§4.4, Figs 7-8) on rendered images, scored point by point.

An aluminium beam is loaded from a 20 N reference to 2000 N in 200 N steps (``bending_scenes``: finite-element
truth, the ``scheimpflug`` rig with a thin lens by default). Every state is measured with the stereo-DIC
pipeline against the left reference image (65 px subsets, step 5, second order), the mean rigid-body motion is
removed as the paper does, and the surface strain is computed on the triangulated point grid
(``measurement.strain``: the strain window by default, per-triangle Cosserat point elements with
``window=None``). Scoring, per load: U, V, W against the truth (left camera frame), strain against the exact
strain and against the truth seen through the same strain window, the neutral axis.

Writes ``metrics.json``, ``report.md``, Fig 7 / Fig 8-style maps (measured, truth, error) and per-point CSV/VTK.
"""
from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from measurement.dic import DICSettings
from labio.atomic import atomic_write_text, atomic_writer
from measurement.image_io import read_grey
from measurement.rigid import fit_rigid, remove_rigid_motion
from measurement.stereo_dic import StereoMatchError, measure_state, reference_shape
from measurement.stereo_io import write_state_vtk
from measurement.strain import surface_strain, virtual_strain_gauge_px
from workbench.experiments.bending.scenes import BENDING_LOADS_N, load_bending_truth, render_bending
from workbench.experiments.calibration.run import render_content, mc_summary
from workbench.experiments.rigid_motion.run import face_roi, finite_or_none, rig_for_name
from workbench.experiments.rigid_motion.scenes import known_fraction_range, paper_optics, speckle_render_content
from workbench.rigs import get_rig
from workbench.store import dataset_record, stored_render
from workbench.points_with_truth import Alignment, write_alignment, write_points_readme, write_points_with_truth
from workbench.rigs import scheimpflug_design_report

#: Default strain window (points per side of the least-squares fit): VSG = 14 * 5 + 65 = 135 px (~4.7 mm).
DEFAULT_STRAIN_WINDOW = 15
#: The paper's map loads (Figs 7-8).
MAP_LOADS_N = (600.0, 1200.0, 1800.0)


def grid_values(values: np.ndarray, grid) -> np.ndarray:
    """Per-point values (N, ...) of the active POIs on the grid's (rows, cols, ...) layout, NaN elsewhere."""
    out = np.full(grid.shape + values.shape[1:], np.nan)
    out[grid.active] = values
    return out


def rms(a) -> float:
    """Root mean square of the finite values (NaN when there are none)."""
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if a.size else float("nan")


def _neutral_axis_mm(E11: np.ndarray, y_mm: np.ndarray, x_mm: np.ndarray, exclude_mm: float = 8.0,
                     min_points: int = 10) -> float:
    """Height (specimen y, mm) where the axial strain changes sign: median over grid columns of a line fit.

    Columns within ``exclude_mm`` of mid-span (the loading nose's local field) are left out; each column's
    E11(y) is fitted by a straight line and its zero crossing taken.
    """
    crossings = []
    for j in range(E11.shape[1]):
        ok = np.isfinite(E11[:, j]) & np.isfinite(y_mm[:, j])
        if ok.sum() < min_points or not np.all(np.abs(x_mm[ok, j]) > exclude_mm):
            continue
        slope, offset = np.polyfit(y_mm[ok, j], E11[ok, j], 1)
        if abs(slope) > 0:
            crossings.append(-offset / slope)
    return float(np.median(crossings)) if crossings else float("nan")


def _strain_invariants(E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frobenius magnitude and area change ``sqrt(det(I + 2E)) - 1`` of (..., 2, 2) strain tensors."""
    magnitude = np.sqrt(np.sum(E ** 2, axis=(-2, -1)))
    C = np.eye(2) + 2.0 * E
    return magnitude, np.sqrt(np.linalg.det(C)) - 1.0


def sampled_peak_strain_ue(truth, subset_size: int, step: int, state: int) -> float:
    """Largest exact strain magnitude (µε) in the lower half of the face at the points of interest a run with this
    subset and step measures (the ROI and grid of :func:`reproduce_bending`; no image is needed)."""
    from measurement.dic import poi_grid

    half = subset_size // 2
    roi = _overlap_roi(truth, face_roi(_FacePoses(truth), half), half, step)
    spec = truth.specs["left"]
    grid = poi_grid((spec.height, spec.width), subset_size, step, roi=roi)
    x, y = grid.x[grid.active], grid.y[grid.active]
    low = y >= y.min() + 0.4 * (y.max() - y.min())      # the lower half of the face (y down), with room to spare
    X0, _ = truth.points_of_interest(np.column_stack([x[low], y[low]]).astype(float))
    lower = np.all(np.isfinite(X0), axis=1) & (X0[:, 1] > 0)
    E, _, _ = truth.strain_truth(X0[lower], state)
    return 1e6 * float(np.nanmax(_strain_invariants(E)[0]))


def strain_goal_scale_law(rig_name: str, lens: str, scale: float, loads, subset_size: int, step: int, seed: int,
                          peak_ue: float, state: int) -> dict:
    """The strain goal (% of the peak the POIs sample) of a run at ``scale``, derived from the full-resolution one.

    With subset, step and strain window fixed in pixels, the displacement noise and the strain gauge length both
    grow as the pixel footprint (1 / scale): the strain noise in µε does not change with scale (to first order;
    measured: 15.1 µε at scale 1, 19.3 µε at 0.25 with 0.46 grey of Monte-Carlo render noise on top). The points,
    though, stay half a subset from the face's edges, a margin that grows as 1 / scale, so the peak strain they
    sample falls; the full-resolution goal (5 % of the full-resolution points' peak) is, in µε, 5 % x
    ``peak_full / peak_here`` of this run's peak. ``peak_full`` is computed on the full-resolution rig's points
    (no rendering)."""
    from workbench.experiments.bending.report import GOALS
    from workbench.experiments.bending.scenes import bending_truth

    full = bending_truth(get_rig(rig_name, 1.0), lens=lens, loads_N=loads, seed=seed)
    peak_full = sampled_peak_strain_ue(full, subset_size, step, state)
    return {"peak_full_resolution_ue": peak_full, "peak_ue": peak_ue, "load_N": float(loads[state]),
            "goal_percent_of_peak": GOALS["strain_percent_of_peak"] * peak_full / peak_ue,
            "law": "strain noise (µε) independent of scale with subset, step and window fixed in px; the points' "
                   "peak strain falls as their margin from the face edge (half a subset) grows as 1 / scale: goal = "
                   f"{GOALS['strain_percent_of_peak']:g} % x peak at full-resolution points / peak here"}


def reproduce_bending(out_dir: str | Path, *, scale: float = 1.0, rig_name: str = "scheimpflug", lens: str = "thin",
                      calib: str = "rendered", seed: int = 0, spp: int = 64, noise_grey: float = 1.0,
                      subset_size: int = 65, step: int = 5, window: int | None = DEFAULT_STRAIN_WINDOW,
                      loads_N=BENDING_LOADS_N, progress: bool = True, store=None,
                      mc_target_grey: float | None = None, calibration_views: tuple[int, int] = (30, 20),
                      renderer: str = "auto", f_number: float | None = 8.0) -> dict:
    """Render (or reuse) the load states, measure them, compute strain, score against truth, write the report.

    The load states are rendered into the dataset store (``store``, default
    :func:`workbench.store.default_store_dir`) under the hash of everything that makes them, recorded through the
    diffraction of a lens at ``f_number`` (550 nm, the rig's pixels; None: ideal optics).
    """
    out_dir = Path(out_dir)
    loads = np.asarray(loads_N, dtype=float)
    rig, rig_text = rig_for_name(calib, rig_name, scale, out_dir, seed, store, mc_target_grey,  # bad file: first
                                  calibration_views)
    content = {"experiment": "bending", "rig": rig_name, "scale": float(scale), "lens": lens, "seed": seed,
               **render_content(spp, mc_target_grey), **speckle_render_content(renderer, lens, mc_target_grey),
               "read_noise_grey": float(noise_grey), "loads_N": [float(v) for v in loads],
               "fe": "ThreePointBending defaults/2"}     # /2: rendered through the generic specimen path
    optics = None if f_number is None else paper_optics(get_rig(rig_name, scale), f_number)
    if optics is not None:                      # ideal-optics datasets keep the hashes they had
        content["optics"] = optics.to_dict()
    images, _ = stored_render("bending", content, lambda folder: render_bending(
        rig_name, folder, scale=scale, lens=lens, spp=spp, seed=seed, noise_grey=noise_grey, loads_N=loads,
        progress=progress, overwrite=True, mc_target_grey=mc_target_grey, renderer=renderer, optics=optics), store)
    truth = load_bending_truth(images)
    settings = DICSettings(subset_size=subset_size, step=step, order=2)
    roi = _overlap_roi(truth, face_roi(_FacePoses(truth), subset_size // 2), subset_size // 2, step)
    left_ref = read_grey(images / truth.files[0]["left"])
    right_ref = read_grey(images / truth.files[0]["right"])
    t0 = time.perf_counter()
    shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, left_ref,
                            right_ref, settings, roi=roi)
    reference_s = time.perf_counter() - t0
    points_dir = out_dir / "points"
    grid = shape.grid
    X0_spec, X_true = truth.points_of_interest(np.column_stack([shape.x, shape.y]).astype(float))
    on_face = np.all(np.isfinite(X0_spec), axis=1)
    ok0 = shape.valid & on_face
    # The calibrated left frame may be turned slightly against the true one: align once on the reference shape.
    R_al, t_al = fit_rigid(shape.X_mm[ok0], X_true[0][ok0])
    alignment = Alignment(R_al, t_al, int(ok0.sum()))
    write_points_readme(points_dir, "three-point bending", _EXTRA_COLUMNS, _OTHER_FILES)
    write_alignment(points_dir, alignment)
    nan3 = np.full((shape.x.size, 3), np.nan)
    write_points_with_truth(points_dir / "reference.csv", shape, None, X_true[0], X_true[0], on_face, alignment,
                            _deformation_columns(np.where(ok0[:, None], 0.0, nan3), np.where(on_face[:, None], 0.0, nan3)))
    write_state_vtk(points_dir / "reference.vtk", shape)
    ref_err = np.linalg.norm(shape.X_mm[ok0] @ R_al.T + t_al - X_true[0][ok0], axis=1)
    X_ref_aligned = shape.X_mm @ R_al.T + t_al
    x_spec_grid, y_spec_grid = grid_values(X0_spec[:, 0], grid), grid_values(X0_spec[:, 1], grid)
    X_true_ref_grid = grid_values(X_true[0], grid)
    peak_load = float(loads.max())

    vsg = virtual_strain_gauge_px(window if window is not None else 2, step, subset_size)
    pairs = None
    if window is not None and shape.subsets is not None:
        from measurement.uncertainty.strain import pair_covariances

        pairs = pair_covariances(shape.reference, shape.subsets, shape.right_match.grid_index, grid.shape, grid.step,
                                 window=window)
    rows, maps = [], {}
    previous = None     # each state seeds the next (measure_state's warm start)
    for k in tqdm(range(1, len(loads)), desc="stereo-DIC + strain per load", disable=not progress):
        load = float(loads[k])
        left_def = read_grey(images / truth.files[k]["left"])
        right_def = read_grey(images / truth.files[k]["right"])
        start = time.perf_counter()
        try:
            state = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape,
                                  left_ref, left_def, right_def, settings, name=f"state {k} ({load:g} N)",
                                  previous=previous)
        except StereoMatchError as error:      # a state that cannot be matched (or fails the sanity check) is skipped
            rows.append({"state": k, "load_N": load, "error": f"{truth.files[k]}: {error}"})
            continue
        previous = state
        stereo_s = time.perf_counter() - start
        # Measured deformation: the mean rigid-body motion taken out (paper §3), then strain on the point grid.
        X_def_aligned = state.X_mm @ R_al.T + t_al
        start = time.perf_counter()
        ok = state.valid & on_face
        # the same points define the rigid motion removed from the measurement and from the truth
        removal = remove_rigid_motion(X_ref_aligned, np.where(ok[:, None], X_def_aligned, np.nan))
        strain = surface_strain(grid_values(X_ref_aligned, grid), grid_values(removal.X1_aligned_mm, grid), window=window)
        strain_s = time.perf_counter() - start
        # Truth: exact displacement of each material point, its exact strain, and the truth through the window.
        U_true = X_true[k] - X_true[0]
        U_meas = state.U_mm @ R_al.T
        err = np.where(ok[:, None], U_meas - U_true, np.nan)
        U_true_def = remove_rigid_motion(X_true[0], np.where(ok[:, None], X_true[k], np.nan)).residual_mm
        write_points_with_truth(points_dir / f"state_{k:02d}.csv", shape, state, X_true[0], X_true[k], on_face,
                                alignment, _deformation_columns(removal.residual_mm, U_true_def))
        write_state_vtk(points_dir / f"state_{k:02d}.vtk", shape, state)
        err_def = np.where(ok[:, None], removal.residual_mm - U_true_def, np.nan)
        E_exact, Q_world, area_exact = truth.strain_truth(X0_spec, k)
        # exact strain expressed in the measured local frame (e1, e2 of each node, aligned frame)
        e1, e2 = strain.e1.reshape(-1, 3)[grid.active.ravel()], strain.e2.reshape(-1, 3)[grid.active.ravel()]
        E_world = np.einsum("nia,nab,njb->nij", Q_world, E_exact, Q_world)
        basis = np.stack([e1, e2], axis=2)
        E_exact_meas = np.einsum("nia,nij,njb->nab", basis, E_world, basis)
        filtered = surface_strain(X_true_ref_grid, grid_values(X_true[k], grid), window=window)
        E_meas = np.stack([np.stack([strain.E11, strain.E12], -1), np.stack([strain.E12, strain.E22], -1)], -2)
        E_filt = np.stack([np.stack([filtered.E11, filtered.E12], -1), np.stack([filtered.E12, filtered.E22], -1)], -2)
        mag_exact, _ = _strain_invariants(E_exact)
        mag_exact_g = grid_values(mag_exact, grid)
        E_exact_g = grid_values(E_exact_meas, grid)
        valid_g = grid_values(ok.astype(float), grid) > 0
        d_filt = np.where(valid_g, strain.magnitude - filtered.magnitude, np.nan)
        d_raw = np.where(valid_g, strain.magnitude - mag_exact_g, np.nan)
        comp_filt = np.where(valid_g[..., None, None], E_meas - E_filt, np.nan)
        comp_raw = np.where(valid_g[..., None, None], E_meas - E_exact_g, np.nan)
        # Peak bending strain: the largest exact strain in the lower half of the face (the tensile fibres, away
        # from the loading nose's contact strain on the top edge, which is reported separately).
        lower = on_face & (X0_spec[:, 1] > 0)
        peak = float(np.nanmax(mag_exact[lower])) if lower.any() else float(np.nanmax(mag_exact[on_face]))
        peak_all = float(np.nanmax(mag_exact[on_face]))
        na_meas = _neutral_axis_mm(np.where(valid_g, strain.E11, np.nan), y_spec_grid, x_spec_grid)
        na_true = _neutral_axis_mm(np.where(np.isfinite(E_exact_g[..., 0, 0]), E_exact_g[..., 0, 0], np.nan),
                                   y_spec_grid, x_spec_grid)
        sigma_E = None
        if pairs is not None and state.cov_U_mm2 is not None:
            from measurement.uncertainty.stereo import triangulation_sensitivity
            from measurement.uncertainty.strain import state_strain_sigma

            cams = (rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
            sigma_E = state_strain_sigma(shape, state, strain, triangulation_sensitivity(*cams, shape.X_mm),
                                         triangulation_sensitivity(*cams, state.X_mm), pairs, X_ref_mm=X_ref_aligned,
                                         rotation=R_al)
        _write_strain_csv(points_dir / f"strain_{k:02d}.csv", grid, strain, E_exact_g, grid_values(mag_exact, grid),
                          grid_values(area_exact, grid), E_filt, filtered, valid_g, sigma_E)
        row = {"state": k, "load_N": load, "points": int(ok.sum()), "points_total": int(ok.size),
               "stereo_s": round(stereo_s, 2), "strain_s": round(strain_s, 3),
               "median_residual_px": float(np.nanmedian(state.residual_px[ok])),
               "p95_residual_px": state.quality.p95_residual_px,
               "U_rmse_um": [rms(1e3 * err[:, i]) for i in range(3)],
               "U_max_um": [float(np.nanmax(np.abs(1e3 * err[:, i]))) for i in range(3)],
               "U_rmse_rigid_removed_um": [rms(1e3 * err_def[:, i]) for i in range(3)],
               "truth_max_displacement_um": float(1e3 * np.nanmax(np.linalg.norm(U_true[on_face], axis=1))),
               "strain_points": int(np.isfinite(d_filt).sum()),
               "strain_magnitude_rmse_vs_filtered_ue": 1e6 * rms(d_filt),
               "strain_magnitude_rmse_vs_exact_ue": 1e6 * rms(d_raw),
               "strain_component_rmse_vs_filtered_ue": {n: 1e6 * rms(comp_filt[..., a, b])
                                                        for n, (a, b) in (("E11", (0, 0)), ("E22", (1, 1)),
                                                                          ("E12", (0, 1)))},
               "strain_component_rmse_vs_exact_ue": {n: 1e6 * rms(comp_raw[..., a, b])
                                                     for n, (a, b) in (("E11", (0, 0)), ("E22", (1, 1)),
                                                                       ("E12", (0, 1)))},
               "peak_truth_strain_ue": 1e6 * peak, "peak_truth_strain_with_nose_contact_ue": 1e6 * peak_all,
               "neutral_axis_mm": {"measured": finite_or_none(na_meas), "truth": finite_or_none(na_true)},
               "area_change_top_bottom": {
                   "measured": [float(np.nanmedian(np.where(y_spec_grid < -0.25 * truth.specimen.height_mm,
                                                            strain.area_change, np.nan))),
                                float(np.nanmedian(np.where(y_spec_grid > 0.25 * truth.specimen.height_mm,
                                                            strain.area_change, np.nan)))]}}
        row["strain_rmse_vs_filtered_percent_of_peak"] = 100 * row["strain_magnitude_rmse_vs_filtered_ue"] / row[
            "peak_truth_strain_ue"]
        rows.append(row)
        if any(abs(load - m) < 1e-6 for m in MAP_LOADS_N) or load == peak_load:
            maps[load] = {"x": x_spec_grid, "y": y_spec_grid,
                          "U": (grid_values(removal.residual_mm, grid), grid_values(U_true_def, grid)),
                          "strain": (strain.magnitude, filtered.magnitude, mag_exact_g),
                          "area": (strain.area_change, filtered.area_change, grid_values(area_exact, grid))}
    metrics = {"rig": rig_name, "calibration": rig_text, "images": str(images),
               "images_dataset": dataset_record("bending", content, images), "lens": lens, "scale": scale,
               **render_content(spp, mc_target_grey), "render_mc": mc_summary(truth.info["render"].get("mc", [])),
               "speckle_renderers": truth.info["render"].get("renderers", {}),
               "speckle_known_fraction": known_fraction_range(truth.info["render"].get("images", [])),
               "noise_grey": noise_grey, "subset_px": subset_size, "step_px": step,
               "strain_window": window if window is not None else "per-triangle (Cosserat point elements)",
               "vsg_px": vsg, "roi_px": list(roi), "points": int(shape.x.size),
               "pixel_footprint_mm": float(np.linalg.norm(truth.pose[1])) / truth.specs["left"].fx,
               "reference_points_triangulated": int(ok0.sum()), "reference_s": round(reference_s, 2),
               "reference_3d_error_um": {"aligned_rms": float(1e3 * np.sqrt(np.mean(ref_err ** 2))),
                                         "aligned_max": float(1e3 * ref_err.max())},
               "beam": truth.beam.to_dict(), "thin_lens": {k: v for k, v in truth.info.items() if k != "render"},
               "states": rows}
    if rig_name == "scheimpflug":
        metrics["scheimpflug_design"] = scheimpflug_design_report()
    from workbench.experiments.bending.report import GOALS
    goal_row = next((r for r in rows if abs(r["load_N"] - GOALS["load_N"]) < 1e-6 and "error" not in r), None)
    if scale != 1.0 and goal_row is not None:
        k_goal = int(np.argmin(np.abs(loads - GOALS["load_N"])))
        metrics["strain_goal_scale_law"] = strain_goal_scale_law(rig_name, lens, scale, loads, subset_size, step, seed,
                                                                 goal_row["peak_truth_strain_ue"], k_goal)
    # the FE truth against beam theory and a mesh-refinement pair, at the goal load
    from scenes.deformation.beam_bending import three_point_bending_report
    metrics["fe_verification"] = three_point_bending_report(truth.beam, load_N=1800.0)
    from workbench.experiments.bending.report import write_bending_report
    write_bending_report(out_dir, metrics, maps)          # adds metrics["goals"]
    atomic_write_text(out_dir / "metrics.json", json.dumps(metrics, indent=2))
    from workbench.reporting.experiment_idics import append_idics
    append_idics(out_dir, "bending", metrics)
    return metrics


def _overlap_roi(truth, roi, half: int, step: int, margin_px: int = 4) -> tuple[int, int, int, int]:
    """Shrink a left-image ROI to the columns whose face points the right camera sees too (the paper's ROI is
    the rectangle in the middle of the face that both cameras see; a beam longer than the right view would
    otherwise leave a band of unmatched points)."""
    x0, y0, x1, y1 = roi
    xs = np.arange(x0, x1 + 1, max(1, step))
    pix = np.concatenate([np.column_stack([xs, np.full(xs.size, y)]) for y in (y0, (y0 + y1) // 2, y1)]).astype(float)
    _, X = truth.points_of_interest(pix)
    uv = truth.project("right", X[0])
    spec = truth.specs["right"]
    m = half + margin_px
    inside = (np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= m) & (uv[:, 0] <= spec.width - 1 - m)
              & (uv[:, 1] >= m) & (uv[:, 1] <= spec.height - 1 - m)).reshape(3, -1).all(axis=0)
    if not inside.any():
        raise ValueError("no part of the left image's face region is seen by the right camera")
    columns = xs[inside]
    return int(columns.min()), int(y0), int(columns.max()), int(y1)


class _FacePoses:
    """Adapter: the rigid-motion ROI helper reads ``specimen``, ``poses``, ``specs`` and ``project``."""

    def __init__(self, truth):
        self.specimen, self.poses, self.specs, self.project = truth.specimen, [truth.pose], truth.specs, truth.project


#: The bending experiment's columns beyond :mod:`workbench.points_with_truth`'s.
_EXTRA_COLUMNS = {
    "Udef_al Vdef_al Wdef_al": "measured deformation: the aligned measurement with the mean rigid-body motion of the "
                               "converged points on the specimen removed (paper §3) | true left camera | mm",
    "Udef_true Vdef_true Wdef_true": "the truth with the rigid motion of the same points removed | true left camera | mm",
}
_OTHER_FILES = {
    "strain_KK.csv": "per grid node (`row`, `col`, pixel `x`, `y`): measured Green-Lagrange strain `E11 E22 E12` in "
                     "the node's local surface frame (e1, e2), principal `E1 E2`, `magnitude`, `area_change`; the exact "
                     "FE strain in the same frame (`E11_exact E22_exact E12_exact`, `magnitude_exact`, "
                     "`area_change_exact`); the exact motion through the same strain window (`*_filtered`: the "
                     "truth the report's strain RMSE is measured against); `scored` = 1 where the node counts; "
                     "`sigma_E11_ue sigma_E22_ue sigma_E12_ue`: the instrument's random uncertainty of the measured "
                     "strain (µε, strain window only)",
}


def _deformation_columns(measured_mm: np.ndarray, true_mm: np.ndarray) -> dict[str, np.ndarray]:
    out = {}
    for j, axis in enumerate("UVW"):
        out[f"{axis}def_al"] = measured_mm[:, j]
    for j, axis in enumerate("UVW"):
        out[f"{axis}def_true"] = true_mm[:, j]
    return out


def _write_strain_csv(path: Path, grid, strain, E_exact, magnitude_exact, area_exact, E_filtered, filtered,
                      scored, sigma=None) -> None:
    """Per-node strain: grid position, left-image pixel, measured E11 E22 E12, E1 E2, magnitude, area change; the
    exact strain in the same local frame and the exact motion through the same window; the scored mask; the
    strain's random uncertainty ``sigma_E11_ue`` ... (µε; NaN for the triangle method, which has no window fit)."""
    sigma = np.full(grid.shape + (3,), np.nan) if sigma is None else sigma
    with atomic_writer(path, "w", newline="") as handle:
        w = csv.writer(handle)
        w.writerow(["row", "col", "x", "y", "E11", "E22", "E12", "E1", "E2", "magnitude", "area_change",
                    "E11_exact", "E22_exact", "E12_exact", "magnitude_exact", "area_change_exact",
                    "E11_filtered", "E22_filtered", "E12_filtered", "magnitude_filtered", "area_change_filtered",
                    "scored", "sigma_E11_ue", "sigma_E22_ue", "sigma_E12_ue"])
        for i in range(grid.shape[0]):
            for j in range(grid.shape[1]):
                w.writerow([i, j, int(grid.x[i, j]), int(grid.y[i, j])]
                           + [f"{v:.6e}" for v in (strain.E11[i, j], strain.E22[i, j], strain.E12[i, j],
                                                   strain.E1[i, j], strain.E2[i, j], strain.magnitude[i, j],
                                                   strain.area_change[i, j], E_exact[i, j, 0, 0], E_exact[i, j, 1, 1],
                                                   E_exact[i, j, 0, 1], magnitude_exact[i, j], area_exact[i, j],
                                                   E_filtered[i, j, 0, 0], E_filtered[i, j, 1, 1],
                                                   E_filtered[i, j, 0, 1], filtered.magnitude[i, j],
                                                   filtered.area_change[i, j])]
                           + [int(bool(scored[i, j]))] + [f"{1e6 * v:.6g}" for v in sigma[i, j]])
