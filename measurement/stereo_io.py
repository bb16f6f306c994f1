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

#: Random uncertainty (standard, 1 sigma) of X, Y, Z and U, V, W, µm; the calibration's (systematic, correlated over
#: all points) part of the same; ``bias_bound_*``: a bound on the interpolation bias (systematic, per point, not in
#: the sigma, :mod:`measurement.uncertainty.bias`); ``sigma_flag``: 0 trusted, 1 the match residual exceeds what the noise explains,
#: 2 no match, 3 no sigma (texture too weak), 4 no sigma (saturated subset) -- :mod:`measurement.uncertainty`.
SIGMA_COLUMNS = ("sigma_X_um", "sigma_Y_um", "sigma_Z_um", "sigma_U_um", "sigma_V_um", "sigma_W_um",
                 "sigma_X_calib_um", "sigma_Y_calib_um", "sigma_Z_calib_um",
                 "sigma_U_calib_um", "sigma_V_calib_um", "sigma_W_calib_um",
                 "bias_bound_X_um", "bias_bound_Y_um", "bias_bound_Z_um",
                 "bias_bound_U_um", "bias_bound_V_um", "bias_bound_W_um", "sigma_flag")
CSV_COLUMNS = ("x", "y", "X", "Y", "Z", "U", "V", "W", "D", "zncc", "residual", "status", "status_name",
               *SIGMA_COLUMNS)
#: Surface strain (:mod:`measurement.stereo_strain`): Green-Lagrange, dimensionless, tensor shear, in the local frame
#: (x = the left image's x projected onto the surface); principal strains e1 >= e2 and the angle of e1 from x (deg);
#: the standard uncertainty of exx, eyy, exy. Written after :data:`CSV_COLUMNS` when a strain is given.
STRAIN_COLUMNS = ("exx", "eyy", "exy", "e1", "e2", "strain_angle_deg", "sigma_exx", "sigma_eyy", "sigma_exy")


def _fmt(value: float) -> str:
    return "nan" if not np.isfinite(value) else f"{value:.9g}"


def state_sigmas(shape: StereoShape, state: StereoState | None = None) -> dict[str, np.ndarray]:
    """The :data:`SIGMA_COLUMNS` of a state (or of the reference shape), (N,) each; NaN where unknown.

    The reference shape's displacement is zero by definition: its sigma_U is 0 (random and calibration).
    """
    n = shape.x.size
    valid = shape.valid if state is None else state.valid
    if state is None:
        sx = _sigmas_um(shape.cov_X_mm2, n)
        su = np.where(valid[:, None], 0.0, np.nan) * np.ones((n, 3))
        cx = _sigmas_um(getattr(shape, "calibration_cov_X_mm2", None), n)
        cu = np.where(valid[:, None] & np.isfinite(cx), 0.0, np.nan) * np.ones((n, 3))
        bx = _values_um(shape.bias_bound_X_mm, n)
        bu = np.where(valid[:, None] & np.isfinite(bx), 0.0, np.nan) * np.ones((n, 3))
        unc = shape.match_uncertainty
        flag = unc.flag.astype(np.int64) if unc is not None else np.full(n, -1)
    else:
        sx, su = _sigmas_um(state.cov_X_mm2, n), _sigmas_um(state.cov_U_mm2, n)
        cx = _sigmas_um(getattr(state, "calibration_cov_X_mm2", None), n)
        cu = _sigmas_um(getattr(state, "calibration_cov_U_mm2", None), n)
        bx, bu = _values_um(state.bias_bound_X_mm, n), _values_um(state.bias_bound_U_mm, n)
        flag = state.flag.astype(np.int64) if state.flag is not None else np.full(n, -1)
    if flag.min(initial=0) >= 0:
        flag = np.where(valid & ~np.isfinite(sx[:, 0]) & (flag == 0), 3, flag)
        flag = np.where(~valid & (flag == 0), 2, flag)
    sx, su = np.where(valid[:, None], sx, np.nan), np.where(valid[:, None], su, np.nan)
    cx, cu = np.where(valid[:, None], cx, np.nan), np.where(valid[:, None], cu, np.nan)
    bx, bu = np.where(valid[:, None], bx, np.nan), np.where(valid[:, None], bu, np.nan)
    values = [*sx.T, *su.T, *cx.T, *cu.T, *bx.T, *bu.T, flag]
    return dict(zip(SIGMA_COLUMNS, values))


def _values_um(values_mm, n: int) -> np.ndarray:
    return np.full((n, 3), np.nan) if values_mm is None else 1e3 * np.asarray(values_mm, dtype=np.float64)


def _sigmas_um(cov_mm2, n: int) -> np.ndarray:
    if cov_mm2 is None:
        return np.full((n, 3), np.nan)
    diag = np.einsum("kii->ki", np.asarray(cov_mm2, dtype=np.float64))
    return 1e3 * np.sqrt(np.where(diag >= 0, diag, np.nan))


def text_lines(columns: list[tuple[str, np.ndarray]]) -> list[str]:
    """Rows of a table as CSV text lines (no line ends), one format per column kind, formatted row by row in C.

    ``columns``: (kind, values (N,)) with kind ``"g"`` (float, ``%.9g``; NaN and +-inf written ``nan``), ``"d"``
    (integer) or ``"s"`` (text, written as it is: no commas or quotes, so no CSV quoting is needed). The same text
    :mod:`csv` writes for these values, ~30x faster than formatting value by value (a 70 000-point state's
    38 columns in ~0.3 s).
    """
    formats, lists = [], []
    for kind, values in columns:
        values = np.asarray(values)
        if kind == "g":
            values = values.astype(np.float64)
            values = np.where(np.isfinite(values), values, np.nan)
            formats.append("%.9g")
        elif kind == "d":
            values = values.astype(np.int64)
            formats.append("%d")
        elif kind == "s":
            formats.append("%s")
        else:
            raise ValueError(f"column kind must be 'g', 'd' or 's', got {kind!r}")
        lists.append(values.tolist())
    row_format = ",".join(formats)
    return [row_format % row for row in zip(*lists)]


def strain_columns(strain) -> list[tuple[str, np.ndarray]]:
    """The columns :data:`STRAIN_COLUMNS` of a :class:`measurement.stereo_strain.StateStrain`, as (kind, values)."""
    sigma = strain.sigma if strain.sigma is not None else np.full((strain.E11.size, 3), np.nan)
    return [("g", v) for v in (strain.E11, strain.E22, strain.E12, strain.E1, strain.E2, strain.angle_deg,
                                *sigma.T)]


def state_columns(shape: StereoShape, state: StereoState | None = None) -> list[tuple[str, np.ndarray]]:
    """The columns :data:`CSV_COLUMNS` of :func:`write_state_csv`, as (kind, values) for :func:`text_lines`."""
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
    sig = state_sigmas(shape, state)
    flag = sig.pop("sigma_flag")
    names = {int(code): Status(int(code)).name.lower() for code in np.unique(status)}
    return [("d", shape.x), ("d", shape.y), *(("g", c) for c in X.T), *(("g", c) for c in U.T), ("g", D),
            ("g", zncc), ("g", residual), ("d", status), ("s", [names[int(v)] for v in status]),
            *(("g", v) for v in sig.values()), ("s", ["" if v < 0 else str(int(v)) for v in flag.tolist()])]


def write_state_csv(path: str | Path, shape: StereoShape, state: StereoState | None = None, strain=None) -> Path:
    """Per-point CSV: left reference pixel (x, y), position X, Y, Z and displacement U, V, W, D (left camera
    frame, mm), ZNCC, triangulation residual (px), status, and the uncertainty (:data:`SIGMA_COLUMNS`, µm); with
    ``strain`` (:class:`measurement.stereo_strain.StateStrain`) the :data:`STRAIN_COLUMNS` after them.
    ``state=None`` writes the reference shape."""
    columns, header = state_columns(shape, state), CSV_COLUMNS
    if strain is not None:
        columns, header = columns + strain_columns(strain), CSV_COLUMNS + STRAIN_COLUMNS
    write_csv_lines(path, header, text_lines(columns))
    return Path(path)


def write_csv_lines(path: str | Path, header, lines: list[str]) -> Path:
    """A CSV file from its header and its text lines (:func:`text_lines`), atomically, with the line ends the
    :mod:`csv` module writes (CRLF)."""
    path = Path(path)
    with atomic_writer(path, "w", newline="") as handle:
        handle.write(",".join(header) + "\r\n")
        if lines:
            handle.write("\r\n".join(lines) + "\r\n")
    return path


def write_state_vtk(path: str | Path, shape: StereoShape, state: StereoState | None = None, strain=None) -> Path:
    """Legacy-VTK POLYDATA of the valid points with displacement (vector), D, ZNCC and residual (scalars), and
    with ``strain`` the :data:`STRAIN_COLUMNS` as scalars."""
    path = Path(path)
    sig = {k: v for k, v in state_sigmas(shape, state).items() if k != "sigma_flag"}
    if strain is not None:
        sig.update({name: values for name, (_, values) in zip(STRAIN_COLUMNS, strain_columns(strain))})
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
    lines += ["%.9g %.9g %.9g" % tuple(row) for row in X.tolist()]
    lines += [f"VERTICES {n} {2 * n}"] + [f"1 {k}" for k in range(n)]
    lines += [f"POINT_DATA {n}", "VECTORS displacement_mm double"]
    lines += ["%.9g %.9g %.9g" % tuple(row) for row in U.tolist()]
    for name, values in (("D_mm", np.linalg.norm(U, axis=1)), ("zncc", zncc), ("residual_px", residual),
                         ("x_px", shape.x[valid]), ("y_px", shape.y[valid]),
                         *((name, values[valid]) for name, values in sig.items())):
        lines += [f"SCALARS {name} double 1", "LOOKUP_TABLE default"] + list(map("{:.9g}".format,
                                                                                  np.asarray(values).tolist()))
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


SUMMARY_COLUMNS = ("state", "left", "right", "result", "points", "measured", "measured_fraction",
                   "median_residual_px", "p95_residual_px", "mean_D_mm",
                   "median_sigma_U_um", "median_sigma_V_um", "median_sigma_W_um",
                   "median_sigma_U_calib_um", "median_sigma_V_calib_um", "median_sigma_W_calib_um",
                   "sigma_mean_U_calib_um", "sigma_mean_V_calib_um", "sigma_mean_W_calib_um",
                   "sigma_flagged_fraction", "noise_source", "error",
                   "strain_points", "max_e1", "max_e1_x_px", "max_e1_y_px", "min_e2",
                   "median_sigma_exx", "median_sigma_eyy", "median_sigma_exy")
_STRAIN_SUMMARY = SUMMARY_COLUMNS[SUMMARY_COLUMNS.index("strain_points"):]


def strain_summary(shape: StereoShape, strain) -> dict:
    """Per-state figures of a :class:`measurement.stereo_strain.StateStrain`: the points with a strain, the largest
    principal strain e1 and where it is (left reference px), the smallest e2, the median sigma of exx, eyy, exy."""
    ok = np.isfinite(strain.E1)
    out = {"strain_points": int(ok.sum())}
    if ok.any():
        i = int(np.nanargmax(np.where(ok, strain.E1, -np.inf)))
        out.update(max_e1=float(strain.E1[i]), max_e1_x_px=float(shape.x[i]), max_e1_y_px=float(shape.y[i]),
                   min_e2=float(np.nanmin(strain.E2[ok])))
    if strain.sigma is not None:
        for k, c in enumerate(("exx", "eyy", "exy")):
            values = strain.sigma[:, k][np.isfinite(strain.sigma[:, k])]
            out[f"median_sigma_{c}"] = float(np.median(values)) if values.size else float("nan")
    return out


def sigma_summary(shape: StereoShape, state: StereoState | None = None) -> dict:
    """Per-state figures of the uncertainty: the median random and calibration sigma of U, V, W over the trusted
    points (of X, Y, Z for the reference shape, whose U is zero), µm; the calibration's sigma of the mean of U over
    the points (the part common to the whole field); the flagged fraction of the measured points; where the noise
    came from."""
    sig = state_sigmas(shape, state)
    flag = sig["sigma_flag"]
    valid = shape.valid if state is None else state.valid
    trusted = valid & (flag == 0)
    out = {}
    for c, r in zip("UVW", "XYZ"):
        name = c if state is not None else r
        for kind in ("", "_calib"):
            values = sig[f"sigma_{name}{kind}_um"][trusted]
            values = values[np.isfinite(values)]
            out[f"median_sigma_{c}{kind}_um"] = float(np.median(values)) if values.size else float("nan")
    common = getattr(state, "calibration_sigma_mean_U_mm", None) if state is not None else None
    for k, c in enumerate("UVW"):
        out[f"sigma_mean_{c}_calib_um"] = float(1e3 * common[k]) if common is not None else float("nan")
    out["sigma_flagged_fraction"] = float(np.count_nonzero(valid & (flag == 1)) / max(1, int(valid.sum())))
    unc = shape.match_uncertainty
    out["noise_source"] = unc.noise_source if unc is not None else ""
    return out


def write_state_summary(path: str | Path, rows: list[dict]) -> Path:
    """One row per state (the reference first): files, measured / measurable points, median and 95th percentile
    of the triangulation residual (px), mean D (mm), the uncertainty (:func:`sigma_summary`; the reference row
    holds the sigma of X, Y, Z under the U, V, W names) and the error of a state that was refused.

    ``rows``: dicts with ``state``, ``left``, ``right``, ``quality`` (:class:`StereoQuality` or None) and
    optionally ``mean_D_mm``, the keys of :func:`sigma_summary` and of :func:`strain_summary`, and ``error``.
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
                             _fmt(row["mean_D_mm"]) if "mean_D_mm" in row else "",
                             *(_fmt(row[c]) if c in row else "" for c in SUMMARY_COLUMNS[10:19]),
                             _fmt(row["sigma_flagged_fraction"]) if "sigma_flagged_fraction" in row else "",
                             row.get("noise_source", ""), row.get("error", ""),
                             *((_fmt(row[c]) if isinstance(row[c], float) else row[c]) if c in row else ""
                               for c in _STRAIN_SUMMARY)])
    return Path(path)
