"""MatchID result exports (DIC 2-D and stereo), read into :class:`workbench.results.ToolResult`.

Layout (MatchID's CSV export, one file per image, named after it: ``Image_0007_0.tiff.csv``): comma-separated, one
row per point inside the ROI (any order), a header of ``group.Name [unit]`` fields, e.g. (MatchID 2024)::

    Coordinates.Image X [Pixel], Coordinates.Image Y [Pixel], coor.X [mm], coor.Y [mm], coor.Z [mm],
    disp.Horizontal Displacement U [mm], disp.Vertical Displacement V [mm], disp.Out-Of-Plane: W [mm], ...,
    strain.Strain-global frame: Exx [ ], ...Eyy [ ], ...Exy [ ], strain.Maximum Principal Strain: EI [ ], ...

or the short form of older versions: ``x_pic, y_pic, x, y, z, u, v, w, exx, eyy, exy, e1, e2, gamma, evm`` (pixels,
then mm). A 2-D analysis without calibration writes its displacements in ``[Pixel]``. Columns are found by what they
are (the group and the unit are read from the name); a point MatchID did not correlate is a row with NaN or empty
displacement. ``coor.*`` is the reference position. The strain's measure and shear convention are not in the file
(its unit is, in brackets): they must be stated (:mod:`workbench.readers.conventions`).

Evidence: MatchID exports committed in Applied-Materials-Technology/pycoatl (MIT; ``data/matchid_dat_2024/
Image_0007_0.tiff.csv``, ``data/matchid_dat_2023/B0010_0.tif.csv``) and its importer's table of both header forms.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from workbench.readers.conventions import StrainConvention, UnstatedStrainError, check_shear, to_green_lagrange

_UNIT = re.compile(r"\[([^\]]*)\]\s*$")
#: What each column is, by the words of its name (long form) or its short name.
_LONG = {"x_px": ("image x", "pixel"), "y_px": ("image y", "pixel"),
         "X": ("coor.x", None), "Y": ("coor.y", None), "Z": ("coor.z", None),
         "U": ("displacement u", None), "V": ("displacement v", None), "W": ("w [", None),
         "exx": ("exx", None), "eyy": ("eyy", None), "exy": ("exy", None),
         "e1": ("principal strain: ei [", None), "e2": ("principal strain: eii [", None)}
_SHORT = {"x_px": "x_pic", "y_px": "y_pic", "X": "x", "Y": "y", "Z": "z", "U": "u", "V": "v", "W": "w",
          "exx": "exx", "eyy": "eyy", "exy": "exy", "e1": "e1", "e2": "e2"}
_LENGTH_MM = {"mm": 1.0, "µm": 1e-3, "um": 1e-3, "m": 1e3}
_STRAIN_UNITS = {"": "1", "-": "1", "%": "%", "µε": "microstrain", "µstrain": "microstrain", "microstrain": "microstrain"}


def unit_of(name: str) -> str | None:
    m = _UNIT.search(name)
    return m.group(1).strip() if m else None


def columns_of(header: list[str]) -> dict[str, str]:
    """Which column of ``header`` holds each quantity (keys of ``_SHORT``), long or short form."""
    if all(_SHORT[k] in header for k in ("x_px", "y_px")):
        return {k: n for k, n in _SHORT.items() if n in header}
    found = {}
    for name in header:
        low = name.lower()
        for key, (words, unit) in _LONG.items():
            if key in found or words not in low:
                continue
            if key in ("U", "V", "W") and not low.startswith("disp"):
                continue
            if key in ("exx", "eyy", "exy", "e1", "e2") and not low.startswith("strain"):
                continue
            if unit is not None and (unit_of(name) or "").lower() != unit:
                continue
            found[key] = name
    return found


def recognises(header: list[str]) -> bool:
    found = columns_of(header)
    return "x_px" in found and "y_px" in found and ("U" in found or "X" in found)


def read_matchid(path: Path, *, strain_convention: StrainConvention | None = None, ignore_strain: bool = False,
                 pixel_shift: float = 0.0):
    """One MatchID CSV export (module notes); ``pixel_shift`` is added to the pixel coordinates."""
    from workbench.readers.table import ResultFormatError, ToolResult, read_table, table_column

    header, rows = read_table(path)
    cols = columns_of(header)
    if "x_px" not in cols or "y_px" not in cols:
        raise ResultFormatError(f"{path}: not a MatchID export: no image-pixel columns ('Coordinates.Image X "
                                f"[Pixel]' or 'x_pic'); the columns are {', '.join(header)}")
    col = lambda k: table_column(path, header, rows, cols[k])  # noqa: E731
    x, y = col("x_px") + pixel_shift, col("y_px") + pixel_shift
    if not all(k in cols for k in "UV"):
        raise ResultFormatError(f"{path}: a MatchID export without displacement columns (U, V); the columns are "
                                f"{', '.join(header)}")
    unit = unit_of(cols["U"]) if cols["U"] != "u" else "mm"
    D = np.column_stack([col(k) for k in ("U", "V", "W") if k in cols])
    valid = np.all(np.isfinite(D), axis=1)
    nan = lambda a: np.where(valid if a.ndim == 1 else valid[:, None], a, np.nan)  # noqa: E731
    u = v = X = U = None
    if unit is not None and unit.lower() == "pixel":
        u, v = nan(D[:, 0]), nan(D[:, 1])
    else:
        if unit not in _LENGTH_MM:
            raise ResultFormatError(f"{path}: column {cols['U']!r}: unknown length unit {unit!r} "
                                    f"(known: {', '.join(_LENGTH_MM)})")
        if "W" not in cols:
            raise ResultFormatError(f"{path}: a calibrated MatchID export without the out-of-plane displacement W")
        U = nan(D * _LENGTH_MM[unit])
        if all(k in cols for k in "XYZ"):
            X = nan(np.column_stack([col(k) for k in "XYZ"]) * _LENGTH_MM[unit]) + U   # coor.*: the reference
    strain = surface = None
    if all(k in cols for k in ("exx", "eyy", "exy")) and not ignore_strain:
        file_unit = unit_of(cols["exx"]) if cols["exx"] != "exx" else None
        if file_unit is not None and file_unit not in _STRAIN_UNITS:
            raise ResultFormatError(f"{path}: column {cols['exx']!r}: unknown strain unit [{file_unit}]")
        if strain_convention is None:
            raise UnstatedStrainError(
                f"{path}: columns {cols['exx']!r}, ... hold strain whose measure and shear MatchID's export does not "
                "state: give --strain-measure, --strain-shear and --strain-unit"
                + (f" (the file's unit: {_STRAIN_UNITS[file_unit]})" if file_unit is not None else "")
                + ", or --ignore-strain")
        if file_unit is not None and _STRAIN_UNITS[file_unit] != strain_convention.unit:
            bracket = cols["exx"][cols["exx"].rindex("["):]
            raise ValueError(f"{path}: --strain-unit {strain_convention.unit} but the file's strain columns are in "
                             f"{bracket} ({_STRAIN_UNITS[file_unit]})")
        if "e1" in cols and "e2" in cols:
            check_shear(path, *(np.where(valid, col(k), np.nan) for k in ("exx", "eyy", "exy", "e1", "e2")),
                        strain_convention, f"{cols['e1']!r}, {cols['e2']!r}")
        E = nan(to_green_lagrange(col("exx"), col("eyy"), col("exy"), strain_convention))
        if U is not None:
            surface = E
        else:
            strain = E
    return ToolResult(path, "MatchID", x, y, valid, u, v, X, U, frame="MatchID's coordinate system", strain=strain,
                      surface_strain=surface)
