"""Score any tool's result against a dataset's truth: the same figures our own pipeline gets.

The truth of each reported point is evaluated exactly at the tool's own reference position
(:func:`workbench.scoring.datasets.point_truth`, sub-pixel positions included), so no interpolation of the truth and no
matching of grids is involved. Points the tool reports off the specimen are counted (``outside_points``) and
left out of the errors.

2-D: error of (u, v) in px against the material point's motion in the left images. 3-D: error of the
displacement (µm) in the left camera frame. A tool that reports 3-D in another frame is aligned by one rigid
fit of its reference positions onto the true ones (``align="rigid"``, Kabsch; the rotation and translation are
reported), or taken as it is (``align="none"``, the default, for tools that state the left camera frame).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.scoring.datasets import Dataset, point_truth
from workbench.results import ToolResult

ALIGNMENTS = ("none", "rigid")


@dataclass(frozen=True)
class StateScore:
    """Errors of one state's result, per point, and their summary."""

    state: int
    label: str
    x_px: np.ndarray
    y_px: np.ndarray
    error_uv_px: np.ndarray | None       # (N, 2), NaN where not scored
    error_U_um: np.ndarray | None        # (N, 3)
    metrics: dict
    strain: object | None = None         # workbench.scoring.strain.StrainScore of a result with surface strain


def rigid_fit(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising ``sum |R a + t - b|^2`` over the rows (Kabsch), (N, 3) -> (3, 3), (3,)."""
    ca, cb = A.mean(0), B.mean(0)
    H = (A - ca).T @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cb - R @ ca


def truth_strain_2d(dataset: Dataset, state: int, x_px: np.ndarray, y_px: np.ndarray, h_px: float = 0.5) -> np.ndarray:
    """Exact 2-D Green-Lagrange strain (exx, eyy, exy) of the left images' motion at the points, (N, 3).

    F = I + grad u with grad u by central differences of the exact point truth at x +- h, y +- h (the truth is
    a smooth function of position: the difference error is of order h^2 times the third derivative, far below
    any DIC strain noise); E = (F^T F - I) / 2.
    """
    d = {}
    for name, dx, dy in (("xp", h_px, 0), ("xm", -h_px, 0), ("yp", 0, h_px), ("ym", 0, -h_px)):
        d[name] = point_truth(dataset, x_px + dx, y_px + dy).uv_left_px[state]
    gx = (d["xp"] - d["xm"]) / (2 * h_px)              # (N, 2): du/dx, dv/dx
    gy = (d["yp"] - d["ym"]) / (2 * h_px)
    F = np.stack([np.stack([1 + gx[:, 0], gy[:, 0]], -1), np.stack([gx[:, 1], 1 + gy[:, 1]], -1)], 1)
    E = 0.5 * (np.einsum("nki,nkj->nij", F, F) - np.eye(2))
    return np.column_stack([E[:, 0, 0], E[:, 1, 1], E[:, 0, 1]])


def _summary(e: np.ndarray, prefix: str, unit: str, axes: str) -> dict:
    """bias, std and RMS per component, RMS and max of the norm, 95th percentile of the norm."""
    ok = np.all(np.isfinite(e), axis=1)
    out = {}
    if not ok.any():
        return {f"{prefix}rms_{unit}": float("nan")}
    e = e[ok]
    for j, a in enumerate(axes):
        out[f"{prefix}bias_{a}_{unit}"] = float(np.mean(e[:, j]))
        out[f"{prefix}std_{a}_{unit}"] = float(np.std(e[:, j]))
        out[f"{prefix}rms_{a}_{unit}"] = float(np.sqrt(np.mean(e[:, j] ** 2)))
    norm = np.linalg.norm(e, axis=1)
    out[f"{prefix}rms_{unit}"] = float(np.sqrt(np.mean(norm ** 2)))
    out[f"{prefix}max_{unit}"] = float(norm.max())
    out[f"{prefix}p95_{unit}"] = float(np.percentile(norm, 95))
    return out


def score_state(dataset: Dataset, state: int, result: ToolResult, align: str = "none",
                strain_window: dict | None = None) -> StateScore:
    """Score ``result`` (reference -> ``state``) against the truth of ``dataset``.

    A 3-D result with surface strain is scored against the exact strain and the strain seen through its window
    (:mod:`workbench.scoring.strain`): ``strain_window`` (``{"window_points": k or None, "fit": ...}``) states the
    window where the result does not.
    """
    if align not in ALIGNMENTS:
        raise ValueError(f"--align {align!r}: choose one of {', '.join(ALIGNMENTS)}")
    if not 1 <= state < dataset.n_states:
        raise ValueError(f"{result.source}: state {state} is not a deformed state of {dataset.folder.name} "
                         f"(1 to {dataset.n_states - 1})")
    if result.has_3d and not dataset.stereo:
        raise ValueError(f"{result.source}: a 3-D result, but {dataset.folder.name} is a 2-D dataset")
    with_strain = result.surface_strain is not None
    if with_strain and not dataset.stereo:
        raise ValueError(f"{result.source}: a surface strain, but {dataset.folder.name} is a 2-D dataset")
    window = strain_window or result.strain_window
    if with_strain and window is None:
        raise ValueError(f"{result.source}: the file holds strain but does not say over what window it was computed; "
                         "give --strain-window K (grid points per side, or 'triangles') and --strain-fit")
    truth = point_truth(dataset, result.x_px, result.y_px, strain=with_strain)
    on = truth.valid
    scored = on & result.valid
    placed = np.isfinite(result.x_px) & np.isfinite(result.y_px)
    # Failed points (NaN or flagged by the tool) count as not measured; rows without a position cannot be
    # placed on the specimen and are counted apart.
    metrics = {"state": state, "label": dataset.labels[state], "points": int(result.x_px.size),
               "truth_points": int(on.sum()), "valid_points": int(scored.sum()),
               "not_measured_points": int(np.sum(on & ~result.valid)),
               "rows_without_position": int(np.sum(~placed)),
               "valid_fraction": float(scored.sum() / on.sum()) if on.any() else float("nan"),
               "outside_points": int(np.sum(result.valid & ~on & placed))}
    e2 = e3 = None
    if result.has_2d:
        e2 = np.column_stack([result.u_px, result.v_px]) - truth.uv_left_px[state]
        e2[~scored] = np.nan
        metrics.update(_summary(e2, "", "px", "uv"))
        if result.sigma_uv_px is not None:
            metrics.update(_sigma_coverage(e2, result.sigma_uv_px, "uv"))
    if result.strain is not None:
        es = 1e6 * (result.strain - truth_strain_2d(dataset, state, result.x_px, result.y_px))
        es[~scored] = np.nan
        metrics.update(_summary(es, "strain_", "microstrain", ("xx", "yy", "xy")))
    if result.has_3d:
        U = np.array(result.U_mm, float)
        if align == "rigid":
            if result.X_mm is None:
                raise ValueError(f"{result.source}: --align rigid needs the 3-D positions (X, Y, Z columns)")
            X0 = result.X_mm - result.U_mm
            ok = scored & np.all(np.isfinite(X0), axis=1)
            if ok.sum() < 3:
                raise ValueError(f"{result.source}: fewer than 3 valid points to align the frames")
            R, t = rigid_fit(X0[ok], truth.X_left_mm[0][ok])
            U = U @ R.T
            metrics["alignment"] = {"R": R.tolist(), "t_mm": t.tolist(),
                                    "rotation_deg": float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))}
            Xa = X0 @ R.T + t
        else:
            Xa = None if result.X_mm is None else result.X_mm - result.U_mm
        e3 = 1e3 * (U - truth.displacement_left_mm[state])
        e3[~scored] = np.nan
        metrics.update(_summary(e3, "", "um", "UVW"))
        if result.sigma_U_mm is not None and align == "none":
            metrics.update(_sigma_coverage(e3, 1e3 * result.sigma_U_mm, "UVW"))
        if align == "none" and result.X_mm is not None:
            hint = _frame_hint(result, truth, state, scored, metrics["rms_um"])
            if hint:
                metrics["frame_hint"] = hint
        if Xa is not None:
            ep = 1e3 * (Xa - truth.X_left_mm[0])
            ep[~scored] = np.nan
            metrics.update(_summary(ep, "position_", "um", "XYZ"))
    strain = None
    if with_strain:
        from workbench.scoring.strain import score_strain

        strain = score_strain(result.x_px, result.y_px, result.surface_strain, scored, truth.X_left_mm[0],
                              truth.X_left_mm[state], truth.strain_left[state], window["window_points"],
                              window.get("fit") or "linear", result.surface_strain_sigma)
        metrics.update(strain.metrics)
    return StateScore(state, dataset.labels[state], result.x_px, result.y_px, e2, e3, metrics, strain)


def _sigma_coverage(error: np.ndarray, sigma: np.ndarray, names) -> dict:
    """How the tool's own sigma covers its error against the truth: per component RMS(error / sigma) and the
    fraction inside +-1.96 sigma (``sigma_rms_z_<c>``, ``sigma_coverage_95_<c>``), over the scored points with a
    sigma. The error here is the *total* error (bias and calibration included), the sigma what the tool claims."""
    out = {}
    for k, c in enumerate(names):
        ok = np.isfinite(error[:, k]) & np.isfinite(sigma[:, k]) & (sigma[:, k] > 0)
        z = error[ok, k] / sigma[ok, k]
        out[f"sigma_rms_z_{c}"] = float(np.sqrt(np.mean(z ** 2))) if z.size else float("nan")
        out[f"sigma_coverage_95_{c}"] = float(np.mean(np.abs(z) < 1.959964)) if z.size else float("nan")
    return out


def _frame_hint(result: ToolResult, truth, state: int, scored: np.ndarray, rms_um: float) -> str | None:
    """A sentence when the tool's 3-D frame does not look like the left camera frame: one rigid fit of its
    reference positions onto the truth cuts the displacement error by more than 10 x."""
    X0 = result.X_mm - result.U_mm
    ok = scored & np.all(np.isfinite(X0), axis=1)
    if ok.sum() < 3 or not np.isfinite(rms_um):
        return None
    R, _ = rigid_fit(X0[ok], truth.X_left_mm[0][ok])
    e = 1e3 * (result.U_mm[ok] @ R.T - truth.displacement_left_mm[state][ok])
    aligned = float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))
    if aligned * 10.0 < rms_um:
        return (f"the result's 3-D frame does not look like the left camera frame: one rigid fit (a "
                f"{np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))):.3g} deg rotation) cuts the error "
                f"from {rms_um:.3g} to {aligned:.3g} µm RMS; score with --align rigid if the tool uses another frame")
    return None
