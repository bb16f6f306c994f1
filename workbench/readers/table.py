"""What every reader of a result file returns (:class:`ToolResult`), the error it raises, and the CSV table helpers
they share (:func:`read_table`, :func:`table_column`). Conventions: :mod:`workbench.results`."""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class ResultFormatError(ValueError):
    """A result file that cannot be read as asked (the message names the file and the column)."""


@dataclass(frozen=True)
class ToolResult:
    """One tool's result for one state (reference -> that state), in this project's conventions.

    Attributes
    ----------
    source : Path
    tool : str
    x_px, y_px : (N,) float, reference positions in the left reference image
    valid : (N,) bool, the tool reports a number it trusts
    u_px, v_px : (N,) float or None, 2-D displacement (NaN where not valid)
    X_mm : (N, 3) float or None, 3-D position in the deformed state, the tool's frame
    U_mm : (N, 3) float or None, 3-D displacement, the tool's frame
    frame : str, the frame of X_mm / U_mm as the tool states it (``"left camera"`` for ours and DICe's default)
    strain : (N, 3) float or None, 2-D Green-Lagrange strain (exx, eyy, exy: tensor shear, not engineering) in
        the left image's pixel axes
    sigma_uv_px : (N, 2) float or None, the tool's own standard uncertainty of u, v
    sigma_U_mm : (N, 3) float or None, the tool's own standard uncertainty of U, V, W (this project's: the random
        and, where known, the calibration part in quadrature)
    surface_strain : (N, 3) float or None, the surface strain of a 3-D result: Green-Lagrange E11, E22, E12
        (dimensionless, tensor shear) in the local frame of :mod:`measurement.strain` (x: the left image's x
        projected onto the surface), converted from the tool's convention
    surface_strain_sigma : (N, 3) float or None, the tool's standard uncertainty of the same
    state : int or None, the dataset state the result is of, where the file says (a file of every state: Ncorr's,
        MultiDIC's); None where the file name or ``--state`` tells
    strain_window : dict or None, how the tool computed its strain, ``{"window_points": k, "fit": f}`` (k None for
        triangles, f ``"linear"`` or ``"quadratic"``) where the file (or its manifest) says; None where it does not
    """

    source: Path
    tool: str
    x_px: np.ndarray
    y_px: np.ndarray
    valid: np.ndarray
    u_px: np.ndarray | None = None
    v_px: np.ndarray | None = None
    X_mm: np.ndarray | None = None
    U_mm: np.ndarray | None = None
    frame: str = "left camera"
    strain: np.ndarray | None = None
    sigma_uv_px: np.ndarray | None = None
    sigma_U_mm: np.ndarray | None = None
    surface_strain: np.ndarray | None = None
    surface_strain_sigma: np.ndarray | None = None
    strain_window: dict | None = None
    state: int | None = None

    @property
    def has_2d(self) -> bool:
        return self.u_px is not None

    @property
    def has_3d(self) -> bool:
        return self.U_mm is not None


def read_table(path: Path, skip_prefixes=("#", "*")) -> tuple[list[str], list[list[str]]]:
    """Header and rows of a CSV (comma, semicolon or whitespace separated; quoted names and spaces after the
    delimiter as VIC-3D writes them; a delimiter after the last field as OpenCorr writes it), skipping comment and
    banner lines."""
    try:
        text = path.read_text(errors="strict")
    except UnicodeDecodeError:
        raise ResultFormatError(f"{path}: not a text file") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith(skip_prefixes)]
    if not lines:
        raise ResultFormatError(f"{path}: no header line and no data")
    sample = lines[0]
    delimiter = "," if "," in sample else (";" if ";" in sample else None)
    if delimiter is None:
        table = [ln.split() for ln in lines]
    else:
        table = [[c.strip() for c in row] for row in csv.reader(lines, delimiter=delimiter, skipinitialspace=True)]
    header, rows = table[0], table[1:]
    if len(header) > 1 and header[-1] == "" and all(r and r[-1] == "" for r in rows):
        header, rows = header[:-1], [r[:-1] for r in rows]          # a trailing delimiter on every line
    bad = [i + 2 for i, r in enumerate(rows) if len(r) != len(header)]
    if bad:
        raise ResultFormatError(f"{path}: line {bad[0]} has a different number of fields than the header "
                                f"({len(header)}: {', '.join(header[:6])}…)")
    return header, rows


def table_column(path: Path, header: list[str], rows, name: str, *, what: str | None = None) -> np.ndarray:
    """Column ``name`` of a :func:`read_table` table as floats; ResultFormatError naming the file, column and row."""
    if name not in header:
        raise ResultFormatError(f"{path}: no column {name!r}{f' ({what})' if what else ''}; the columns are "
                                f"{', '.join(header)}")
    j = header.index(name)
    out = np.empty(len(rows))
    for i, row in enumerate(rows):
        try:
            out[i] = float(row[j])
        except ValueError:
            raise ResultFormatError(f"{path}: column {name!r}, data row {i + 1}: {row[j]!r} is not a number") from None
    return out
