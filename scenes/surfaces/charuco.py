"""ChArUco calibration boards (truth side): a printed checkerboard whose white squares hold ArUco markers, in
OpenCV's layout; the same truth corners and imperfections as :class:`scenes.surfaces.checkerboard.Checkerboard`.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from scenes._checks import finite_number
from scenes.surfaces.checkerboard import Checkerboard

# ------------------------------------------------------------------------------------------------------------
# ChArUco board
#: Largest side of a ChArUco print's texture, texels: bounds the search for a texel on which every marker edge
#: falls (:attr:`CharucoBoard.texels_per_square`).
_MAX_TEXTURE_SIDE = 8192


def _aruco_dictionary(name: str):
    """OpenCV's predefined ArUco dictionary ``cv2.aruco.<name>``, or ValueError naming ``dictionary``.

    Only the dictionary's bit patterns (data) come from OpenCV; the board's geometry is built here.
    """
    import cv2

    if not (isinstance(name, str) and name.startswith("DICT_") and isinstance(getattr(cv2.aruco, name, None), int)):
        known = ", ".join(sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_")))
        raise ValueError(f"dictionary must name one of OpenCV's predefined ArUco dictionaries ({known}), got {name!r}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


@lru_cache(maxsize=16)
def _marker_cells(name: str, count: int) -> np.ndarray:
    """Black cells of markers 0..count-1 of dictionary ``name``, with their one-cell black border,
    shape (count, b + 2, b + 2) bool, row 0 at the top of the printed marker (b: the dictionary's bits per side)."""
    d = _aruco_dictionary(name)
    side = d.markerSize + 2
    return np.stack([d.generateImageMarker(k, side, borderBits=1) < 128 for k in range(count)])


@dataclass(frozen=True)
class CharucoBoard(Checkerboard):
    """A printed ChArUco board: a checkerboard whose white squares hold ArUco markers (OpenCV's layout).

    Everything about the checkerboard is :class:`Checkerboard`'s (board frame, ``squares``, ``square_mm``, the
    white margin, ``dark``/``light``, and all imperfections: print scale, bow, corner noise, which move a
    square's marker with it); the truth points are the same inner corners, :meth:`true_corners_board_mm`, in
    the same order, which is also the order of OpenCV's ChArUco corner ids (row by row from the top-left
    inner corner, x fastest).

    Layout (OpenCV >= 4.6 ``cv::aruco::CharucoBoard``, non-legacy pattern): square ``(row i, column j)`` of the
    checkered area (``i, j`` from 0 at the top left, x right, y down as the print is seen) is black when
    ``i + j`` is even, so the top-left square is black, as :class:`Checkerboard`'s; every white square holds
    a marker, centred, ``marker_mm`` wide, with ids 0, 1, ... in row-major order of the white squares, i.e.
    ``id = (i * columns + j) // 2``. A marker is the dictionary's ``b x b`` bit cells inside a one-cell black
    border, so its ``(b + 2)`` cells are ``marker_mm / (b + 2)`` wide. Only the bit patterns come from OpenCV
    (:func:`cv2.aruco.getPredefinedDictionary`); the geometry is built here.

    Parameters (in addition to :class:`Checkerboard`'s)
    ----------------------------------------------------
    marker_mm : float, mm
        Side of one marker including its black border, ``0 < marker_mm < square_mm``.
    dictionary : str
        Name of an OpenCV predefined dictionary, e.g. ``"DICT_4X4_50"``, ``"DICT_5X5_100"``; it must hold at
        least one marker per white square (``columns * rows // 2``; 54 for 12 x 9 squares).

    The print is a nearest-neighbour texture of :attr:`texels_per_square` texels per square: square edges
    (hence the truth corners) are exact, and so is every marker edge when :attr:`markers_on_texels` (the
    texel is chosen so, e.g. 8 texels for ``marker_mm = 0.75 square_mm`` with 4 x 4 bits); otherwise marker
    edges are rounded to the nearest texel (at most ``square_mm / (2 texels_per_square)``), which moves no
    corner.
    """

    marker_mm: float = 3.75
    dictionary: str = "DICT_4X4_100"

    def __post_init__(self):
        super().__post_init__()
        marker = finite_number("marker_mm", self.marker_mm)
        if not 0 < marker < self.square_mm:
            raise ValueError(f"marker_mm must satisfy 0 < marker_mm < square_mm ({self.square_mm:g} mm), got {marker}")
        size = len(_aruco_dictionary(self.dictionary).bytesList)
        if self.marker_count > size:
            raise ValueError(f"dictionary {self.dictionary} holds {size} markers, a board of {self.squares[0]} x "
                             f"{self.squares[1]} squares needs {self.marker_count}")

    @property
    def marker_count(self) -> int:
        """Number of markers, one per white square: ``columns * rows // 2``."""
        return self.squares[0] * self.squares[1] // 2

    @property
    def marker_bits(self) -> int:
        """Bit cells per marker side, without the border (4 for ``DICT_4X4_*``)."""
        return int(_aruco_dictionary(self.dictionary).markerSize)

    def _marker_layout(self) -> tuple[float, float]:
        """(offset, cell) of a marker inside its square, both as fractions of ``square_mm``."""
        ratio = self.marker_mm / self.square_mm
        return 0.5 * (1.0 - ratio), ratio / (self.marker_bits + 2)

    @property
    def _sheet_squares(self) -> tuple[int, int]:
        """(rows, cols) of squares on the sheet including the margin."""
        return self.squares[1] + 2 * self.margin_squares, self.squares[0] + 2 * self.margin_squares

    @property
    def texels_per_square(self) -> int:
        """Texels per square edge: the smallest n on which every marker edge falls on a texel edge (to 1e-9 of
        a texel), searched up to a texture side of 8192 texels; that largest n if none does."""
        offset, cell = self._marker_layout()
        n_max = max(1, _MAX_TEXTURE_SIDE // max(self._sheet_squares))
        for n in range(1, n_max + 1):
            if abs(n * offset - round(n * offset)) < 1e-9 and abs(n * cell - round(n * cell)) < 1e-9:
                return n
        return n_max

    @property
    def markers_on_texels(self) -> bool:
        """True when every marker edge of the texture is exact (see :attr:`texels_per_square`)."""
        offset, cell = self._marker_layout()
        n = self.texels_per_square
        return abs(n * offset - round(n * offset)) < 1e-9 and abs(n * cell - round(n * cell)) < 1e-9

    def _dark_texels(self) -> np.ndarray:
        """Black texels of the nominal print, shape (rows * n, cols * n) bool, row 0 at y_min (n texels/square)."""
        n = self.texels_per_square
        rows, cols = self._sheet_squares
        m = self.margin_squares
        # Texel centres in units of squares, from the top-left corner of the checkered area.
        ty = (np.arange(rows * n) + 0.5) / n - m
        tx = (np.arange(cols * n) + 0.5) / n - m
        i, j = np.floor(ty).astype(int), np.floor(tx).astype(int)
        I, J = np.meshgrid(i, j, indexing="ij")
        inside = (I >= 0) & (I < self.squares[1]) & (J >= 0) & (J < self.squares[0])
        dark = inside & ((I + J) % 2 == 0)
        offset, cell = self._marker_layout()
        side = self.marker_bits + 2
        cy, cx = np.floor((ty - i - offset) / cell).astype(int), np.floor((tx - j - offset) / cell).astype(int)
        CY, CX = np.meshgrid(cy, cx, indexing="ij")
        in_marker = inside & ((I + J) % 2 == 1) & (CY >= 0) & (CY < side) & (CX >= 0) & (CX < side)
        ids = (I * self.squares[0] + J) // 2
        cells = _marker_cells(self.dictionary, self.marker_count)
        dark[in_marker] = cells[ids[in_marker], CY[in_marker], CX[in_marker]]
        return dark

    def texture(self) -> np.ndarray:
        """Nominal print, :attr:`texels_per_square` texels per square including the margin, row 0 at y_min,
        shape (rows n, cols n) float32, radiance."""
        return np.where(self._dark_texels(), self.dark, self.light).astype(np.float32)

    def is_dark(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """True where nominal board point (x, y) is printed black (squares and marker cells; off the sheet: False)."""
        x, y = np.asarray(x_mm, dtype=float), np.asarray(y_mm, dtype=float)
        dark = self._dark_texels()
        x0, _, y0, _ = self.extent_board_mm()
        texel = self.square_mm / self.texels_per_square
        ix, iy = np.floor((x - x0) / texel), np.floor((y - y0) / texel)
        inside = (ix >= 0) & (ix < dark.shape[1]) & (iy >= 0) & (iy < dark.shape[0])
        iy_c = np.clip(iy, 0, dark.shape[0] - 1).astype(int)
        ix_c = np.clip(ix, 0, dark.shape[1] - 1).astype(int)
        return inside & dark[iy_c, ix_c]

    def _square_patch_uv(self, rows: int, cols: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """uv of each square patch spanning that square's block of :meth:`texture`, so that the marker follows
        its (printed, bent) square; vertex order of :meth:`Checkerboard.board_mesh`."""
        a = np.arange(n + 1) / n
        u = (np.arange(cols)[None, :, None, None] + a[None, None, None, :]) / cols
        v = (np.arange(rows)[:, None, None, None] + a[None, None, :, None]) / rows
        u, v = np.broadcast_arrays(u, v)
        return np.stack([u.ravel(), v.ravel()], axis=1), self.texture()
