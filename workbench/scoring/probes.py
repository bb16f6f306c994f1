"""What a user reads off a field at chosen places: line profiles and virtual extensometers, against the truth.

* :func:`line_profile`: along a line of the left reference image (e.g. through a hole or a notch root), the tool's
  strain at its grid points nearest the line, beside the truth through the tool's window and the exact truth;
* :func:`extensometer`: two points of the left reference image as the ends of a virtual extensometer (VIC-3D's and
  MatchID's "extensometer" tool): the distance between the two material points in the reference and in a state,
  from the tool's 3-D positions (bilinear on its grid) and from the exact truth at the very same pixels.

Pixels as everywhere in the project: left reference image, OpenCV convention (integer pixel centres).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.scoring.strain import grid_layout


def parse_segment(text: str, option: str) -> tuple[float, float, float, float]:
    """``"X0,Y0,X1,Y1"`` (px) -> a tuple; ValueError naming ``option`` otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 4 or not all(np.isfinite(values)):
        raise ValueError(f"{option} {text!r}: give X0,Y0,X1,Y1 in px of the left reference image")
    if values[:2] == values[2:]:
        raise ValueError(f"{option} {text!r}: the two ends are the same point")
    return values


@dataclass(frozen=True)
class LineProfile:
    """Samples along a line: ``s_px`` (N,) distance from its start; ``x_px, y_px`` the result's grid points used;
    ``measured``, ``windowed``, ``exact`` (N, 5) E11, E22, E12, E1, E2 (NaN where a sample has no point)."""

    segment: tuple
    s_px: np.ndarray
    x_px: np.ndarray
    y_px: np.ndarray
    measured: np.ndarray
    windowed: np.ndarray
    exact: np.ndarray


def line_profile(x_px, y_px, measured, windowed, exact, segment) -> LineProfile:
    """The strain along ``segment`` (x0, y0, x1, y1) px: one sample per grid step, each the grid point nearest the
    line's point there (none where that node is more than half a step away or has no value).

    ``x_px, y_px`` (N,) the result's points; ``measured, windowed, exact`` (N, 5) per point
    (:class:`workbench.scoring.strain.StrainScore`).
    """
    layout = grid_layout(x_px, y_px)
    x0, y0, x1, y1 = segment
    length = float(np.hypot(x1 - x0, y1 - y0))
    s = np.arange(0.0, length + 1e-9, layout.step_px)
    px, py = x0 + (x1 - x0) * s / length, y0 + (y1 - y0) * s / length
    node_of = np.full(layout.shape, -1, np.int64)
    ok = layout.rows >= 0
    node_of[layout.rows[ok], layout.cols[ok]] = np.flatnonzero(ok)
    j = np.rint((px - layout.origin_px[0]) / layout.step_px).astype(np.int64)
    i = np.rint((py - layout.origin_px[1]) / layout.step_px).astype(np.int64)
    inside = (i >= 0) & (j >= 0) & (i < layout.shape[0]) & (j < layout.shape[1])
    index = np.full(s.size, -1, np.int64)
    index[inside] = node_of[i[inside], j[inside]]

    def take(a):
        out = np.full((s.size,) + np.shape(a)[1:], np.nan)
        out[index >= 0] = np.asarray(a)[index[index >= 0]]
        return out

    return LineProfile(tuple(segment), s, take(np.asarray(x_px, float)), take(np.asarray(y_px, float)),
                       take(measured), take(windowed), take(exact))


def bilinear_on_grid(layout, values: np.ndarray, x: float, y: float) -> np.ndarray:
    """``values`` (N, k) of a grid's points at the pixel (x, y), bilinear from the four surrounding nodes; NaN where
    one of them has no finite value (no extrapolation, no filling of holes)."""
    grid = layout.on_grid(values)
    rows, cols = layout.shape
    fx = (x - layout.origin_px[0]) / layout.step_px
    fy = (y - layout.origin_px[1]) / layout.step_px
    if rows < 2 or cols < 2 or not (0 <= fx <= cols - 1 and 0 <= fy <= rows - 1):
        return np.full(values.shape[1:], np.nan)
    j0, i0 = min(int(np.floor(fx)), cols - 2), min(int(np.floor(fy)), rows - 2)
    tx, ty = fx - j0, fy - i0
    i1, j1 = i0 + 1, j0 + 1
    corners = [(grid[i0, j0], (1 - tx) * (1 - ty)), (grid[i0, j1], tx * (1 - ty)), (grid[i1, j0], (1 - tx) * ty),
               (grid[i1, j1], tx * ty)]
    used = [(v, w) for v, w in corners if w > 0]
    if any(not np.all(np.isfinite(v)) for v, _ in used):
        return np.full(values.shape[1:], np.nan)
    return sum(w * v for v, w in used)


def extensometer(result, truth, state: int, segment) -> dict:
    """A virtual extensometer between the two ends of ``segment`` (x0, y0, x1, y1) px, in ``state``.

    ``result``: a 3-D :class:`workbench.results.ToolResult`; ``truth``: :class:`workbench.scoring.datasets.PointTruth`
    of the two ends (``point_truth(dataset, [x0, x1], [y0, y1])``). Returns the gauge length and its change (mm, µm)
    and the engineering strain ``L / L0 - 1`` of the gauge, measured and true; NaN where the tool has no value at
    an end.
    """
    x0, y0, x1, y1 = segment
    layout = grid_layout(result.x_px, result.y_px)
    Xk = np.where(result.valid[:, None], result.X_mm, np.nan)
    X0 = Xk - result.U_mm
    ends = [(x0, y0), (x1, y1)]
    A0, B0 = (bilinear_on_grid(layout, X0, *p) for p in ends)
    Ak, Bk = (bilinear_on_grid(layout, Xk, *p) for p in ends)
    L0, Lk = float(np.linalg.norm(B0 - A0)), float(np.linalg.norm(Bk - Ak))
    T0 = float(np.linalg.norm(truth.X_left_mm[0][1] - truth.X_left_mm[0][0]))
    Tk = float(np.linalg.norm(truth.X_left_mm[state][1] - truth.X_left_mm[state][0]))
    out = {"segment_px": list(map(float, segment)), "state": int(state),
           "length_mm": L0, "true_length_mm": T0,
           "change_um": 1e3 * (Lk - L0), "true_change_um": 1e3 * (Tk - T0),
           "strain_microstrain": 1e6 * (Lk / L0 - 1.0) if L0 > 0 else float("nan"),
           "true_strain_microstrain": 1e6 * (Tk / T0 - 1.0) if T0 > 0 else float("nan")}
    out["error_microstrain"] = out["strain_microstrain"] - out["true_strain_microstrain"]
    return out
