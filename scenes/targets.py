"""Calibration targets: the paper's printed checkerboard as an exact, textured plane.

Board frame (mm): origin at the first inner corner, x along a row of corners, y along a column, z into the
board (a camera looking at the printed face sees it along +z, as OpenCV's calibration object). Each square
is one texel of a nearest-neighbour texture, so the square edges are mathematically sharp and the rendered
pixels are the exact area integrals of the printed pattern (up to Monte-Carlo sampling).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.surfaces import TexturedSurface


@dataclass(frozen=True)
class Checkerboard:
    """A printed checkerboard.

    Parameters
    ----------
    squares : (columns, rows)
        Number of squares, 12 x 9 in the paper (11 x 8 inner corners).
    square_mm : float
        Edge of one square, 5 mm in the paper.
    margin_squares : int
        White border around the squares, in squares (detectors need a quiet zone).
    dark, light : float
        Emitted radiance of the black and white print (the exposure maps radiance to grey levels).
    """

    squares: tuple[int, int] = (12, 9)
    square_mm: float = 5.0
    margin_squares: int = 1
    dark: float = 0.1
    light: float = 0.9

    def __post_init__(self):
        if self.squares[0] < 3 or self.squares[1] < 3:
            raise ValueError(f"a checkerboard needs at least 3 x 3 squares, got {self.squares}")
        if not self.square_mm > 0:
            raise ValueError(f"square_mm must be positive, got {self.square_mm}")

    @property
    def inner_corners(self) -> tuple[int, int]:
        """(columns, rows) of inner corners, OpenCV's ``patternSize``."""
        return self.squares[0] - 1, self.squares[1] - 1

    def corners_board_mm(self) -> np.ndarray:
        """Inner corners in the board frame, row by row (x fastest), shape (N, 3), mm."""
        nx, ny = self.inner_corners
        jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
        return np.stack([jj.ravel() * self.square_mm, ii.ravel() * self.square_mm, np.zeros(nx * ny)], axis=1)

    def extent_board_mm(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the printed sheet including the margin, mm."""
        m = (1 + self.margin_squares) * self.square_mm
        nx, ny = self.inner_corners
        return -m, (nx - 1) * self.square_mm + m, -m, (ny - 1) * self.square_mm + m

    def is_dark(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """True where board point (x, y) is printed black: the square left-above the origin is black."""
        col = np.floor(np.asarray(x_mm) / self.square_mm)
        row = np.floor(np.asarray(y_mm) / self.square_mm)
        x0, x1, y0, y1 = self.extent_board_mm()
        inside = ((x_mm >= x0 + self.margin_squares * self.square_mm) & (x_mm < x1 - self.margin_squares * self.square_mm)
                  & (y_mm >= y0 + self.margin_squares * self.square_mm) & (y_mm < y1 - self.margin_squares * self.square_mm))
        return inside & ((col + row) % 2 == 0)

    def texture(self) -> np.ndarray:
        """One texel per square including the margin, row 0 at y_min, shape (rows, cols), radiance."""
        x0, x1, y0, y1 = self.extent_board_mm()
        cols = int(round((x1 - x0) / self.square_mm))
        rows = int(round((y1 - y0) / self.square_mm))
        xc = x0 + (np.arange(cols) + 0.5) * self.square_mm
        yc = y0 + (np.arange(rows) + 0.5) * self.square_mm
        X, Y = np.meshgrid(xc, yc)
        return np.where(self.is_dark(X, Y), self.dark, self.light).astype(np.float32)

    def radiance_at(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Printed radiance at board points (off the sheet: 0, the black background)."""
        x0, x1, y0, y1 = self.extent_board_mm()
        on_sheet = (x_mm >= x0) & (x_mm < x1) & (y_mm >= y0) & (y_mm < y1)
        return np.where(on_sheet, np.where(self.is_dark(x_mm, y_mm), self.dark, self.light), 0.0)

    def surface(self, R_world_from_board: np.ndarray, t_world_from_board_mm: np.ndarray) -> TexturedSurface:
        """The sheet as an emissive textured quad placed in the world, ``X_world = R X_board + t``."""
        x0, x1, y0, y1 = self.extent_board_mm()
        corners = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=float)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
        # Winding so that the face normal is -z_board: the printed side faces the camera.
        faces = np.array([[0, 2, 1], [0, 3, 2]])
        R = np.asarray(R_world_from_board, dtype=float)
        verts = corners @ R.T + np.asarray(t_world_from_board_mm, dtype=float).reshape(3)
        return TexturedSurface(vertices_mm=verts, faces=faces, uv=uv, texture=self.texture(), filter="nearest")
