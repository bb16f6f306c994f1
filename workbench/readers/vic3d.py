"""VIC-3D (and VIC-2D) result exports (Correlated Solutions), read into :class:`workbench.results.ToolResult`.

Layout (VIC's "export to CSV"): one file per image pair; a header of double-quoted names separated by a comma and
spaces (``"X",  "Y",  "Z",  "U",  "V",  "W",  "exx", ... "sigma",  "x",  "y",  "u",  "v", ...``), then comma-separated
numbers. Columns are found by name (the set depends on what the user exported); case matters (``x`` is a pixel,
``X`` a position):

* ``x, y``: the subset centre in the reference image of camera 1, px (0-based pixel centres: OpenCV's);
* ``u, v``: its image displacement, px; ``sigma``: the match's one-standard-deviation confidence, px; **-1 where
  VIC did not correlate the point** (the other fields of that row are placeholders);
* ``X, Y, Z``: the reference position, ``U, V, W`` the displacement, in the calibration's length unit (mm unless
  stated), in VIC's coordinate system: camera 1's unless the user applied a transform (score with ``--align rigid``
  then);
* ``exx, eyy, exy, e1, e2``: strain in VIC's local surface frame; Lagrange (Green-Lagrange, tensor shear) is VIC's
  default, but engineering, Hencky and Euler-Almansi strain are written under the same names: the file does not say
  which, so the convention must be stated (:mod:`workbench.readers.conventions`); ``gamma`` is the angle of e1 (rad).

Evidence: the header and the ``sigma = -1`` rows of a VIC-3D export committed in sandialabs/matcal (BSD-3-Clause,
``matcal/core/tests/unit/test_reference/data_importer/17_A-4B_pull-sys1-0000_0.csv``); Correlated Solutions'
knowledge-base article "Strain tensors and criteria in Vic" for the strain options.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.readers.conventions import StrainConvention, UnstatedStrainError, check_shear, to_green_lagrange

#: Columns a VIC export must have to be read: the reference pixel and VIC's match confidence.
REQUIRED = ("x", "y", "sigma")
STRAIN = ("exx", "eyy", "exy")


def recognises(header: list[str]) -> bool:
    return all(c in header for c in REQUIRED)


def read_vic(path: Path, *, strain_convention: StrainConvention | None = None, ignore_strain: bool = False,
             pixel_shift: float = 0.0, length_scale_mm: float = 1.0):
    """One VIC-3D/VIC-2D CSV export (module notes). ``pixel_shift`` is added to x, y (0 for VIC's 0-based pixel
    centres); ``length_scale_mm`` is one length unit of X..W in mm."""
    from workbench.readers.table import ResultFormatError, ToolResult, read_table, table_column

    header, rows = read_table(path)
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise ResultFormatError(f"{path}: not a VIC export: no column {', '.join(repr(c) for c in missing)}; the "
                                f"columns are {', '.join(header)}")
    col = lambda n: table_column(path, header, rows, n)  # noqa: E731
    sigma = col("sigma")
    valid = np.isfinite(sigma) & (sigma >= 0.0)          # VIC writes sigma = -1 where it did not correlate
    x, y = col("x") + pixel_shift, col("y") + pixel_shift
    nan = lambda a: np.where(valid if a.ndim == 1 else valid[:, None], a, np.nan)  # noqa: E731
    u = v = X = U = None
    if "u" in header and "v" in header:
        u, v = nan(col("u")), nan(col("v"))
    if all(c in header for c in "UVW"):
        U = nan(np.column_stack([col(c) for c in "UVW"]) * length_scale_mm)
        if all(c in header for c in "XYZ"):
            X = nan(np.column_stack([col(c) for c in "XYZ"]) * length_scale_mm) + U     # X, Y, Z: the reference
    if u is None and U is None:
        raise ResultFormatError(f"{path}: a VIC export without displacement columns (u, v or U, V, W); the columns "
                                f"are {', '.join(header)}")
    strain = surface = None
    if all(c in header for c in STRAIN) and not ignore_strain:
        if strain_convention is None:
            raise UnstatedStrainError(
                f"{path}: columns exx, eyy, exy hold strain, but a VIC export does not say which (Lagrange is VIC's "
                "default; engineering, Hencky and Euler-Almansi are written under the same names): give "
                "--strain-measure, --strain-shear and --strain-unit (VIC's default: green-lagrange, tensor, 1), or "
                "--ignore-strain")
        if "e1" in header and "e2" in header:
            check_shear(path, *(np.where(valid, col(c), np.nan) for c in ("exx", "eyy", "exy", "e1", "e2")),
                        strain_convention, "e1, e2")
        E = nan(to_green_lagrange(col("exx"), col("eyy"), col("exy"), strain_convention))
        if U is not None:
            surface = E
        else:
            strain = E
    sigma_uv = np.column_stack([sigma, sigma]) if u is not None else None
    return ToolResult(path, "VIC-3D" if U is not None else "VIC-2D", x, y, valid, u, v, X, U,
                      frame="VIC's coordinate system (camera 1 unless transformed)", strain=strain,
                      sigma_uv_px=None if sigma_uv is None else nan(sigma_uv), surface_strain=surface)
