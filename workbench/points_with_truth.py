"""Per-point stereo files with the truth beside the measurement, so any figure can be recomputed from them.

Each state's CSV holds the instrument's own columns (:data:`measurement.stereo_io.CSV_COLUMNS`: position and
displacement in the CALIBRATED left camera frame, as ``workbench stereo`` writes them) followed by

* ``X_al, Y_al, Z_al, U_al, V_al, W_al``: the same measurement in the TRUE left camera frame, through the one
  rigid alignment the experiment fitted (``X_al = R X + t``, ``U_al = R U``; ``alignment.json`` holds R, t and
  the points it was fitted on),
* ``X_true, Y_true, Z_true, U_true, V_true, W_true, D_true``: the exact position of the same material point in
  this state and its displacement from the reference state, true left camera frame (mm),
* ``on_specimen``: 1 where the left reference pixel's ray hits the specimen (the truth exists), 0 elsewhere,
* any experiment-specific columns (e.g. the deformation after the rigid motion is removed).

A point the instrument could not measure keeps NaN in the measured columns and its status; its truth is still
written, so a user sees what was lost.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text
from measurement.stereo_io import CSV_COLUMNS, state_columns, text_lines, write_csv_lines

TRUTH_COLUMNS = ("X_al", "Y_al", "Z_al", "U_al", "V_al", "W_al", "X_true", "Y_true", "Z_true", "U_true", "V_true",
                 "W_true", "D_true", "on_specimen")


@dataclass(frozen=True)
class Alignment:
    """``X_true_frame = R @ X_calibrated_frame + t_mm``: the rigid map from the instrument's calibrated left camera
    frame onto the true left camera frame, fitted on ``points`` reference-state points (Kabsch)."""

    R: np.ndarray
    t_mm: np.ndarray
    points: int
    fitted_on: str = "the reference-state points triangulated on the specimen"

    def to_dict(self) -> dict:
        angle = float(np.degrees(np.arccos(np.clip((np.trace(self.R) - 1) / 2, -1.0, 1.0))))
        return {"maps": "calibrated left camera frame (the instrument's) -> true left camera frame (the truth's)",
                "formula": "X_al = R @ X + t_mm; U_al = R @ U", "R": np.asarray(self.R).tolist(),
                "t_mm": np.asarray(self.t_mm).tolist(), "rotation_deg": angle, "points": int(self.points),
                "fitted_on": self.fitted_on}


def write_points_with_truth(path: str | Path, shape, state, X_true_ref_mm: np.ndarray, X_true_mm: np.ndarray,
                            on_specimen: np.ndarray, alignment: Alignment,
                            extra: dict[str, np.ndarray] | None = None) -> Path:
    """One state's CSV: the instrument's columns, the aligned measurement, the truth (module docstring).

    Parameters
    ----------
    shape : measurement.stereo_dic.StereoShape
        The reference shape (its N points define the rows).
    state : measurement.stereo_dic.StereoState or None
        The measured state; None writes the reference state (displacements zero).
    X_true_ref_mm, X_true_mm : (N, 3) float
        True positions of the points' material points in the reference state and in this state, true left camera
        frame, mm (NaN off the specimen).
    on_specimen : (N,) bool
    alignment : Alignment
    extra : {column: (N,) float}, optional
        Further columns, written after the truth.
    """
    path = Path(path)
    n = shape.x.size
    extra = extra or {}
    for name, values in extra.items():
        if np.shape(values) != (n,):
            raise ValueError(f"{path}: extra column {name!r} has shape {np.shape(values)}, expected ({n},)")
    if state is None:
        X, U = shape.X_mm, np.where(shape.valid[:, None], 0.0, np.nan) * np.ones((n, 3))
    else:
        X, U = state.X_mm, state.U_mm
    R, t = np.asarray(alignment.R, float), np.asarray(alignment.t_mm, float)
    X_al, U_al = X @ R.T + t, U @ R.T
    U_true = X_true_mm - X_true_ref_mm
    D_true = np.linalg.norm(U_true, axis=1)
    columns = [*state_columns(shape, state), *(("g", c) for c in (*X_al.T, *U_al.T, *X_true_mm.T, *U_true.T)),
               ("g", D_true), ("d", np.asarray(on_specimen, dtype=bool)), *(("g", v) for v in extra.values())]
    return write_csv_lines(path, [*CSV_COLUMNS, *TRUTH_COLUMNS, *extra], text_lines(columns))


def write_alignment(folder: str | Path, alignment: Alignment) -> Path:
    """``alignment.json`` in ``folder``: the rigid map the aligned columns went through."""
    path = Path(folder) / "alignment.json"
    atomic_write_text(path, json.dumps(alignment.to_dict(), indent=1) + "\n")
    return path


def write_points_readme(folder: str | Path, experiment: str, extra_columns: dict[str, str] | None = None,
                        other_files: dict[str, str] | None = None) -> Path:
    """``README.md`` in the per-point folder: what each file and column is, in which frame and unit."""
    lines = [f"# Per-point results of the {experiment} experiment, with their truth", "",
             "`reference.csv`, `state_KK.csv`: one row per point of interest (left reference pixel `x`, `y`).", "",
             "| columns | what | frame | unit |", "|---|---|---|---|",
             "| `X Y Z`, `U V W`, `D` | measured position in the state, displacement from the reference, its norm | "
             "calibrated left camera (the instrument's) | mm |",
             "| `zncc`, `residual`, `status`, `status_name` | match quality, triangulation residual, status "
             "(`converged` or why not) | | –, px |",
             "| `sigma_X_um ... sigma_W_um`, `sigma_*_calib_um`, `bias_bound_*_um`, `sigma_flag` | the instrument's "
             "uncertainty of each number: random part, the calibration's (common to all points; NaN when the "
             "calibration has no covariance), the interpolation bias bound, and the flag (0 trusted, 1 residual "
             "above the noise, 2 no match, 3 texture too weak, 4 saturated) | calibrated left camera | µm |",
             "| `X_al Y_al Z_al`, `U_al V_al W_al` | the measurement mapped by `alignment.json` (X_al = R X + t, "
             "U_al = R U) | true left camera | mm |",
             "| `X_true Y_true Z_true`, `U_true V_true W_true`, `D_true` | exact position of the same material point "
             "in the state, its displacement from the reference, its norm | true left camera | mm |",
             "| `on_specimen` | 1 where the truth exists (the reference pixel's ray hits the specimen) | | 0/1 |"]
    for name, text in (extra_columns or {}).items():
        lines.append(f"| `{name}` | {text} |")
    lines += ["", "The error of a point is `U_al - U_true` (or `D - D_true`: the norm needs no alignment); the "
              "figures of the report use the points with `status_name == converged` and `on_specimen == 1`.", ""]
    for name, text in (other_files or {}).items():
        lines.append(f"- `{name}`: {text}")
    lines.append("- `alignment.json`: R, t of the alignment and the points it was fitted on.")
    lines.append("- `*.vtk`: the measured points for ParaView (calibrated frame).")
    path = Path(folder) / "README.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
