"""Points of interest (POIs): a regular grid over a region of interest.

A POI is an integer pixel ``(x, y)`` (column, row) at the centre of a square subset of ``2M + 1`` pixels. The
grid keeps its 2-D layout so reliability-guided propagation can walk from a point to its four neighbours.
The region of interest selects POI *centres*; a subset may reach outside the ROI (that is what lets a DIC
measure up to the ROI edge), but a subset that leaves the image gets the OUT_OF_IMAGE status.

Without a ROI the grid keeps every subset, and the interpolant's support around it, inside the image for
any motion of less than a pixel (:func:`interpolation_margin_px`), so a default grid has no OUT_OF_IMAGE
point at zero displacement.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bspline import degree_of, support_margin


@dataclass(frozen=True)
class PoiGrid:
    """A grid of points of interest.

    Attributes
    ----------
    x, y : ndarray of int64, shape (n_rows, n_cols)
        Column and row of every grid node, px.
    active : ndarray of bool, shape (n_rows, n_cols)
        True where the node is a POI (inside the ROI and the mask).
    subset_size : int
        Odd subset width ``2M + 1``, px.
    step : int
        Grid spacing, px.
    """

    x: np.ndarray
    y: np.ndarray
    active: np.ndarray
    subset_size: int
    step: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.x.shape

    @property
    def half(self) -> int:
        return self.subset_size // 2

    @property
    def count(self) -> int:
        return int(self.active.sum())


def check_subset_size(subset_size: int) -> int:
    """Return ``subset_size`` as int after checking it is odd and >= 5."""
    if isinstance(subset_size, bool) or int(subset_size) != subset_size:
        raise ValueError(f"subset size must be an integer, got {subset_size!r}")
    subset_size = int(subset_size)
    if subset_size < 5 or subset_size % 2 == 0:
        raise ValueError(f"subset size must be odd and >= 5 (2M + 1 pixels), got {subset_size}")
    return subset_size


def interpolation_margin_px(interpolation: str | int = "biquintic") -> int:
    """Pixels the B-spline needs between a subset's edge and the image border, 3 (biquintic) or 2 (bicubic).

    IC-GN samples the deformed image at a point ``x`` only where the spline's whole support is inside the
    image: ``lo <= x < cols - hi`` with ``(lo, hi)`` = (2, 3) for the quintic, (1, 2) for the cubic spline
    (:func:`.bspline.support_margin`), else the point is OUT_OF_IMAGE. A subset edge pixel ``m`` pixels from
    the border may therefore move by anything less than one pixel, either way, when ``m = hi = lo + 1``.
    """
    low, high = support_margin(degree_of(interpolation))
    return max(low + 1, high)


def poi_grid(image_shape: tuple[int, int], subset_size: int, step: int,
             roi: tuple[int, int, int, int] | None = None, mask: np.ndarray | None = None,
             interpolation: str | int = "biquintic") -> PoiGrid:
    """Regular POI grid over a rectangle and/or mask.

    Parameters
    ----------
    image_shape : (rows, cols)
        Shape of the reference image.
    subset_size : int
        Odd subset width 2M + 1, px.
    step : int
        Grid spacing, px (>= 1).
    roi : (x0, y0, x1, y1), optional
        Rectangle of POI centres, px, ``x0 <= x < x1``, ``y0 <= y < y1``. None: the whole image less a border of
        ``M + interpolation_margin_px(interpolation)`` pixels, starting exactly there: every subset and its
        interpolation support then stay in the image for any motion below one pixel.
    mask : ndarray of bool, shape (rows, cols), optional
        POI centres must also fall where the mask is True.
    interpolation : {'biquintic', 'bicubic'} or {5, 3}
        The interpolant the default ROI leaves room for (biquintic, the wider, unless told).

    Returns
    -------
    PoiGrid
    """
    subset_size = check_subset_size(subset_size)
    if isinstance(step, bool) or int(step) != step or int(step) < 1:
        raise ValueError(f"step must be a positive integer, got {step!r}")
    step = int(step)
    rows, cols = int(image_shape[0]), int(image_shape[1])
    half = subset_size // 2
    if roi is None:
        border = half + interpolation_margin_px(interpolation)
        x0, y0, x1, y1 = border, border, cols - border, rows - border
        if x1 <= x0 or y1 <= y0:
            raise ValueError(f"the {cols} x {rows} px image is too small for a {subset_size} px subset: a "
                             f"point of interest needs {border} px to each border ({half} px of half subset "
                             f"and {border - half} px for the interpolation), i.e. an image of at least "
                             f"{2 * border + 1} x {2 * border + 1} px; choose a smaller subset")
    else:
        if len(roi) != 4:
            raise ValueError(f"roi must be (x0, y0, x1, y1), got {roi!r}")
        x0, y0, x1, y1 = (int(round(float(v))) for v in roi)
        if not (0 <= x0 < x1 <= cols and 0 <= y0 < y1 <= rows):
            raise ValueError(f"roi {roi} is empty or outside the {cols} x {rows} image "
                             f"(need 0 <= x0 < x1 <= {cols}, 0 <= y0 < y1 <= {rows})")
    xs = np.arange(x0, x1, step, dtype=np.int64)
    ys = np.arange(y0, y1, step, dtype=np.int64)
    if xs.size == 0 or ys.size == 0:
        raise ValueError(f"roi ({x0}, {y0}, {x1}, {y1}) holds no point of interest at step {step}")
    grid_x, grid_y = np.meshgrid(xs, ys)
    active = np.ones(grid_x.shape, dtype=bool)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.dtype != bool:
            raise ValueError(f"mask must be boolean, got dtype {mask.dtype}")
        if mask.shape != (rows, cols):
            raise ValueError(f"mask shape {mask.shape} does not match the image shape {(rows, cols)}")
        active &= mask[grid_y, grid_x]
        if not active.any():
            raise ValueError("the mask selects no point of interest")
    return PoiGrid(grid_x, grid_y, active, subset_size, step)
