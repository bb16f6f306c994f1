"""Writing stereo-DIC results: one CSV and one legacy-VTK point cloud (for ParaView) per state.

Every file is written atomically (:mod:`labio.atomic`): whole or not at all, write errors name the file.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from measurement.dic import Status
from labio.atomic import atomic_write_text, atomic_writer
from measurement.stereo_dic import StereoShape, StereoState

CSV_COLUMNS = ("x", "y", "X", "Y", "Z", "U", "V", "W", "D", "zncc", "residual", "status", "status_name")


def _fmt(value: float) -> str:
    return "nan" if not np.isfinite(value) else f"{value:.9g}"


def state_rows(shape: StereoShape, state: StereoState | None = None) -> list[list[str]]:
    """The rows of :func:`write_state_csv` (columns :data:`CSV_COLUMNS`), as text, one per point."""
    if state is None:
        X = shape.X_mm
        U = np.zeros_like(X)
        U[~shape.valid] = np.nan
        zncc, residual = shape.right_match.zncc, shape.residual_px
        status = np.where(shape.valid, int(Status.CONVERGED),
                          np.where(shape.right_match.status != Status.CONVERGED, shape.right_match.status,
                                   int(Status.DIVERGED)))
    else:
        X, U, zncc, residual, status = state.X_mm, state.U_mm, state.zncc, state.residual_px, state.status
    D = np.linalg.norm(U, axis=1)
    return [[str(int(shape.x[k])), str(int(shape.y[k])), *(_fmt(v) for v in X[k]), *(_fmt(v) for v in U[k]),
             _fmt(D[k]), _fmt(zncc[k]), _fmt(residual[k]), str(int(status[k])), Status(int(status[k])).name.lower()]
            for k in range(shape.x.size)]


def write_state_csv(path: str | Path, shape: StereoShape, state: StereoState | None = None) -> Path:
    """Per-point CSV: left reference pixel (x, y), position X, Y, Z and displacement U, V, W, D (left camera
    frame, mm), ZNCC, triangulation residual (px) and status. ``state=None`` writes the reference shape."""
    path = Path(path)
    with atomic_writer(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS)
        writer.writerows(state_rows(shape, state))
    return path


def write_state_vtk(path: str | Path, shape: StereoShape, state: StereoState | None = None) -> Path:
    """Legacy-VTK POLYDATA of the valid points with displacement (vector), D, ZNCC and residual (scalars)."""
    path = Path(path)
    if state is None:
        valid = shape.valid
        X, U = shape.X_mm[valid], np.zeros((int(valid.sum()), 3))
        zncc, residual = shape.right_match.zncc[valid], shape.residual_px[valid]
    else:
        valid = state.valid
        X, U, zncc, residual = state.X_mm[valid], state.U_mm[valid], state.zncc[valid], state.residual_px[valid]
    n = X.shape[0]
    lines = ["# vtk DataFile Version 3.0", "stereo-DIC points (left camera frame, mm)", "ASCII", "DATASET POLYDATA",
             f"POINTS {n} double"]
    lines += [f"{a:.9g} {b:.9g} {c:.9g}" for a, b, c in X]
    lines += [f"VERTICES {n} {2 * n}"] + [f"1 {k}" for k in range(n)]
    lines += [f"POINT_DATA {n}", "VECTORS displacement_mm double"]
    lines += [f"{a:.9g} {b:.9g} {c:.9g}" for a, b, c in U]
    for name, values in (("D_mm", np.linalg.norm(U, axis=1)), ("zncc", zncc), ("residual_px", residual),
                         ("x_px", shape.x[valid]), ("y_px", shape.y[valid])):
        lines += [f"SCALARS {name} double 1", "LOOKUP_TABLE default"] + [f"{v:.9g}" for v in values]
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


SUMMARY_COLUMNS = ("state", "left", "right", "result", "points", "measured", "measured_fraction",
                   "median_residual_px", "p95_residual_px", "mean_D_mm", "error")


def write_state_summary(path: str | Path, rows: list[dict]) -> Path:
    """One row per state (the reference first): files, measured / measurable points, median and 95th percentile
    of the triangulation residual (px), mean D (mm), and the error of a state that was refused.

    ``rows``: dicts with ``state``, ``left``, ``right``, ``quality`` (:class:`StereoQuality` or None) and
    optionally ``mean_D_mm`` and ``error``.
    """
    with atomic_writer(Path(path), "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(SUMMARY_COLUMNS)
        for row in rows:
            q = row.get("quality")
            writer.writerow([row["state"], row["left"], row["right"], "skipped" if row.get("error") else "measured",
                             "" if q is None else q.points, "" if q is None else q.measured,
                             "" if q is None else _fmt(q.measured_fraction),
                             "" if q is None else _fmt(q.median_residual_px),
                             "" if q is None else _fmt(q.p95_residual_px),
                             _fmt(row["mean_D_mm"]) if "mean_D_mm" in row else "", row.get("error", "")])
    return Path(path)
