"""OpenCorr result tables (``saveTable2D`` and the stereo ``saveTable2DS``), read into
:class:`workbench.results.ToolResult`.

Layout (OpenCorr's ``IO2D``, ``src/oc_io.cpp``): comma-separated (the delimiter is the caller's choice), one row per
point of interest, a header line, and in current versions a delimiter after the last field of every line:

* 2-D: ``x, y, u, v, u0, v0, ZNCC, iteration, convergence, feature, exx, eyy, exy[, subset_rx, subset_ry]``: the
  point in the reference image (px, 0-based), its displacement (px), the initial guess, the match's ZNCC;
* stereo: ``x, y, u, v, w, r1r2 ZNCC, r1t1 ZNCC, r1t2 ZNCC, r2_x, r2_y, t1_x, t1_y, t2_x, t2_y, ref_x, ref_y, ref_z,
  tar_x, tar_y, tar_z, exx, eyy, ezz, exy, eyz, ezx[, ...]``: the point in view 1 of the reference (px), its
  displacement ``u, v, w = tar - ref`` and the reference and deformed positions in the calibration's world frame
  (its length unit).

A point OpenCorr could not match carries a **negative ZNCC**, a code: -1 too few feature neighbours, -2 no RANSAC
consensus, -3 subset out of the image or a bad initial guess, -4 no convergence, -5 NaN (stereo: in any of its three
ZNCC columns). ZNCC = 0 is a success of the feature-only initial guess. The 2-D strain (pixel gradients; the small
(Cauchy) strain by default: ``--strain-measure cauchy``, tensor shear) needs its convention stated; the stereo table's strain is a 3-D tensor of
the world frame, not a surface strain in a surface frame, and is not read.

Evidence: vincentjzy/OpenCorr 44532cc (MPL-2.0): ``src/oc_io.cpp`` (the writers), ``src/oc_icgn.cpp`` and
``src/oc_feature_affine.cpp`` (the ZNCC codes), ``src/oc_strain.cpp`` (the strain defaults), and the example results
``examples/2d_dic/oht_cfrp_4_fftcc_icgn1_r16.csv``, ``examples/3d_dic/GT4-0273_0_epipolar_sift_r16.csv`` (written by
an older version: no trailing delimiter, no subset columns).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.readers.conventions import StrainConvention, UnstatedStrainError, to_green_lagrange

REQUIRED_2D = ("x", "y", "u", "v", "ZNCC")
REQUIRED_STEREO = ("x", "y", "u", "v", "w", "r1r2 ZNCC", "r1t1 ZNCC", "r1t2 ZNCC", "tar_x", "tar_y", "tar_z")


def recognises(header: list[str]) -> bool:
    return all(c in header for c in REQUIRED_STEREO) or all(c in header for c in REQUIRED_2D)


def read_opencorr(path: Path, *, strain_convention: StrainConvention | None = None, ignore_strain: bool = False,
                  pixel_shift: float = 0.0, length_scale_mm: float = 1.0):
    """One OpenCorr result table (module notes)."""
    from workbench.readers.table import ResultFormatError, ToolResult, read_table, table_column

    header, rows = read_table(path)
    stereo = all(c in header for c in REQUIRED_STEREO)
    if not stereo and not all(c in header for c in REQUIRED_2D):
        missing = [c for c in REQUIRED_2D if c not in header]
        raise ResultFormatError(f"{path}: not an OpenCorr table: no column {', '.join(repr(c) for c in missing)}; the "
                                f"columns are {', '.join(header)}")
    col = lambda n: table_column(path, header, rows, n)  # noqa: E731
    x, y = col("x") + pixel_shift, col("y") + pixel_shift
    if stereo:
        zncc = np.column_stack([col(c) for c in ("r1r2 ZNCC", "r1t1 ZNCC", "r1t2 ZNCC")])
        valid = np.all(np.isfinite(zncc) & (zncc >= 0.0), axis=1)        # a negative ZNCC is a failure code
        U = np.column_stack([col(c) for c in "uvw"]) * length_scale_mm
        X = np.column_stack([col(f"tar_{c}") for c in "xyz"]) * length_scale_mm
        valid &= np.all(np.isfinite(U), axis=1)
        U[~valid], X[~valid] = np.nan, np.nan
        return ToolResult(path, "OpenCorr", x, y, valid, X_mm=X, U_mm=U, frame="OpenCorr's world frame (the "
                          "calibration's: view 1's camera unless it was set otherwise)")
    zncc = col("ZNCC")
    u, v = col("u"), col("v")
    valid = np.isfinite(zncc) & (zncc >= 0.0) & np.isfinite(u) & np.isfinite(v)
    strain = None
    if all(c in header for c in ("exx", "eyy", "exy")) and not ignore_strain:
        if strain_convention is None:
            raise UnstatedStrainError(
                f"{path}: columns exx, eyy, exy hold strain whose convention the table does not state (OpenCorr's "
                "default is the small (Cauchy) strain, tensor shear; Green-Lagrange is an option): give "
                "--strain-measure, --strain-shear and --strain-unit, or --ignore-strain")
        strain = to_green_lagrange(col("exx"), col("eyy"), col("exy"), strain_convention)
        strain[~valid] = np.nan
    return ToolResult(path, "OpenCorr", x, y, valid, np.where(valid, u, np.nan), np.where(valid, v, np.nan),
                      strain=strain)
