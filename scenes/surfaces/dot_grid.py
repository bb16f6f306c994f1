"""Symmetric dot-grid calibration targets (truth side): round dots printed on a flat board; the truth points are the
dot centres, the mesh an exact polygon of each dot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenes._checks import finite_number, is_int
from scenes.surfaces.checkerboard import DARK_UV, FACET_TOLERANCE_MM, LIGHT_UV
from scenes.surfaces.textured_surface import TexturedSurface

# ------------------------------------------------------------------------------------------------------------
# Dot (circle) grid
@dataclass(frozen=True)
class DotGrid:
    """A printed symmetric grid of round dots, perfect (flat, exact print); the truth points are the dot centres.

    Board frame (mm): origin at the centre of the first dot, x along a row of dots, y along a column, z into
    the board (as :class:`Checkerboard`). Dot ``k`` (row by row, x fastest) is centred at
    ``(j pitch_mm, i pitch_mm, 0)``, ``k = i cols + j``.

    Parameters
    ----------
    pattern_size : (cols, rows)
        Dots per row and per column (OpenCV's ``patternSize``), each >= 2.
    pitch_mm : float, mm
        Centre-to-centre distance of neighbouring dots.
    diameter_mm : float, mm
        Dot diameter, ``0 < diameter_mm < pitch_mm`` (dots may not touch).
    margin_pitches : int
        Plain border around the grid, in pitches, beyond the half pitch around the outer dots (>= 0).
    dark, light : float
        Emitted radiance of the dark and the light print.
    dark_dots : bool
        True: dark dots on a light sheet (default); False: light dots on a dark sheet.
    polygon_sides : int or None
        Sides of the regular polygon that stands for each circle in the mesh; None: the smallest multiple
        of 8 whose inscribed polygon stays within ``FACET_TOLERANCE_MM`` (0.05 µm) of the circle
        (352 sides for a 2.5 mm dot). Any even count keeps the polygon's centroid on the true centre.

    Notes
    -----
    Rendering: :meth:`surface` is always a triangle mesh (:meth:`board_mesh`): the sheet is cut into one square
    cell per pitch around every dot, each a fan (the dot) plus a ring of quads to the cell's edge, both colours
    picked from a 2-texel nearest-filter texture, so every dot edge is mathematically sharp and the rendered
    pixels are exact area integrals of the print (up to Monte-Carlo sampling).

    **Perspective eccentricity** (why the truth is *not* the centre of the imaged ellipse). The image of a circle under perspective is an ellipse (a conic) whose centre is *not* the image of the
    circle's centre unless the board is parallel to the image plane (e.g. Heikkilä, 2000, IEEE TPAMI 22(10),
    "Geometric camera calibration using circular control points"; Mallon & Whelan, 2007, Pattern Recognition
    Letters 28(8)). A blob detector finds the centroid of the imaged dot; the truth of a dot is the
    projection of its true 3-D centre (:meth:`true_corners_board_mm` projected by the truth camera). The
    difference, the *eccentricity error*, is zero for a board parallel to the image plane and grows with the
    tilt; its scale is ``f r^2 / Z^2`` px (f in px, dot radius r at distance Z): 0.03 px for the paper's rig
    at quarter resolution and 2.5 mm dots, of which tilted views show ~0.005-0.025 px (measured in
    ``tests/test_targets_charuco_dots.py``; 4x that at full resolution). It is a property of
    the target, not of the renderer: use :meth:`dot_outlines_board_mm` to compute the imaged outlines and
    their centroids, and report detection errors against both.
    """

    pattern_size: tuple[int, int] = (11, 8)
    pitch_mm: float = 5.0
    diameter_mm: float = 2.5
    margin_pitches: int = 1
    dark: float = 0.1
    light: float = 0.9
    dark_dots: bool = True
    polygon_sides: int | None = None

    def __post_init__(self):
        size = self.pattern_size
        if not (isinstance(size, tuple) and len(size) == 2 and all(is_int(c) and c >= 2 for c in size)):
            raise ValueError(f"pattern_size must be (cols, rows), integers >= 2, got {size!r}")
        pitch = finite_number("pitch_mm", self.pitch_mm)
        if not pitch > 0:
            raise ValueError(f"pitch_mm must be positive, got {pitch}")
        d = finite_number("diameter_mm", self.diameter_mm)
        if not 0 < d < pitch:
            raise ValueError(f"diameter_mm must satisfy 0 < diameter_mm < pitch_mm ({pitch:g} mm), got {d}")
        if not (is_int(self.margin_pitches) and self.margin_pitches >= 0):
            raise ValueError(f"margin_pitches must be an integer >= 0, got {self.margin_pitches!r}")
        finite_number("dark", self.dark)
        finite_number("light", self.light)
        if not isinstance(self.dark_dots, (bool, np.bool_)):
            raise ValueError(f"dark_dots must be True or False, got {self.dark_dots!r}")
        sides = self.polygon_sides
        if sides is not None and not (is_int(sides) and sides >= 8 and sides % 8 == 0):
            raise ValueError(f"polygon_sides must be None or a multiple of 8 (>= 8), got {sides!r}")

    # --------------------------------------------------------------------------------------------------------
    # Geometry (nominal = true: the grid is perfect)
    @property
    def radius_mm(self) -> float:
        return 0.5 * self.diameter_mm

    @property
    def inner_corners(self) -> tuple[int, int]:
        """(cols, rows) of truth points, the name :class:`Checkerboard` uses for OpenCV's ``patternSize``."""
        return self.pattern_size

    @property
    def is_perfect(self) -> bool:
        """Always True: the dot grid has no imperfection model (yet)."""
        return True

    def corners_board_mm(self) -> np.ndarray:
        """Nominal dot centres in the board frame, row by row (x fastest), shape (N, 3), mm."""
        nx, ny = self.pattern_size
        jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
        return np.stack([jj.ravel() * self.pitch_mm, ii.ravel() * self.pitch_mm, np.zeros(nx * ny)], axis=1)

    def true_corners_board_mm(self) -> np.ndarray:
        """The true dot centres (the truth points), same order as :meth:`corners_board_mm`, (N, 3) mm."""
        return self.corners_board_mm()

    def dot_outlines_board_mm(self, points_per_dot: int = 256) -> np.ndarray:
        """Points on every true circle, counter-clockwise from +x, shape (N, points_per_dot, 3), mm (z = 0)."""
        if not (is_int(points_per_dot) and points_per_dot >= 3):
            raise ValueError(f"points_per_dot must be an integer >= 3, got {points_per_dot!r}")
        t = 2.0 * np.pi * np.arange(points_per_dot) / points_per_dot
        ring = self.radius_mm * np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], axis=1)
        return self.corners_board_mm()[:, None, :] + ring[None]

    def extent_board_mm(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the printed sheet including the margin, mm."""
        nx, ny = self.pattern_size
        m = (0.5 + self.margin_pitches) * self.pitch_mm
        return -m, (nx - 1) * self.pitch_mm + m, -m, (ny - 1) * self.pitch_mm + m

    def outline_board_mm(self) -> np.ndarray:
        """Corners of the dotted area (half a pitch around the outer dot centres), board frame, (4, 3) mm: the
        outline that must stay in view (:func:`workbench.experiments.calibration.views.board_outline_mm`)."""
        nx, ny = self.pattern_size
        h = 0.5 * self.pitch_mm
        x0, x1, y0, y1 = -h, (nx - 1) * self.pitch_mm + h, -h, (ny - 1) * self.pitch_mm + h
        return np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=float)

    def is_dark(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """True where nominal board point (x, y) is printed dark (off the sheet: False)."""
        x, y = np.asarray(x_mm, dtype=float), np.asarray(y_mm, dtype=float)
        nx, ny = self.pattern_size
        p = self.pitch_mm
        j = np.clip(np.rint(x / p), 0, nx - 1)
        i = np.clip(np.rint(y / p), 0, ny - 1)
        in_dot = np.hypot(x - j * p, y - i * p) < self.radius_mm
        x0, x1, y0, y1 = self.extent_board_mm()
        on_sheet = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
        return on_sheet & (in_dot if self.dark_dots else ~in_dot)

    def radiance_at(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Nominal printed radiance at board points (off the sheet: 0, the black background)."""
        x0, x1, y0, y1 = self.extent_board_mm()
        on_sheet = (x_mm >= x0) & (x_mm < x1) & (y_mm >= y0) & (y_mm < y1)
        return np.where(on_sheet, np.where(self.is_dark(x_mm, y_mm), self.dark, self.light), 0.0)

    def texture(self, texels_per_pitch: int = 40, supersampling: int = 4) -> np.ndarray:
        """A raster of the nominal print (each texel the mean radiance of ``supersampling^2`` sub-samples), row
        0 at y_min, shape (rows, cols) float32: a preview and a 2-D image source. :meth:`surface` does not use
        it (its dots are exact polygons, not texels)."""
        if not (is_int(texels_per_pitch) and texels_per_pitch >= 1 and is_int(supersampling) and supersampling >= 1):
            raise ValueError(f"texels_per_pitch and supersampling must be integers >= 1, got "
                             f"{texels_per_pitch!r}, {supersampling!r}")
        x0, x1, y0, y1 = self.extent_board_mm()
        step = self.pitch_mm / (texels_per_pitch * supersampling)
        xs = x0 + (np.arange(int(round((x1 - x0) / step))) + 0.5) * step
        ys = y0 + (np.arange(int(round((y1 - y0) / step))) + 0.5) * step
        X, Y = np.meshgrid(xs, ys)
        fine = self.radiance_at(X, Y)
        s = supersampling
        return fine.reshape(len(ys) // s, s, len(xs) // s, s).mean(axis=(1, 3)).astype(np.float32)

    # --------------------------------------------------------------------------------------------------------
    # Rendering
    def sides(self) -> int:
        """Sides of each dot's polygon: ``polygon_sides`` or the smallest multiple of 8 with
        ``r (1 - cos(pi / N)) <= FACET_TOLERANCE_MM`` (the inscribed polygon's largest gap to the circle)."""
        if self.polygon_sides is not None:
            return int(self.polygon_sides)
        n = math.pi / math.acos(1.0 - FACET_TOLERANCE_MM / self.radius_mm)
        return max(8, 8 * math.ceil(n / 8))

    def board_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The sheet as a triangle mesh in the board frame.

        Returns
        -------
        vertices_mm : (V, 3) float, board frame, mm
        faces : (F, 3) int, face normals toward -z_board (the printed side)
        uv : (V, 2) float, the centre of the dark or the light texel of ``texture``
        texture : (1, 2) float32, radiance ``[[dark, light]]``

        Every cell (one pitch square around a dot, or a margin cell) is cut along the N rays from its centre at
        angles ``2 pi k / N`` (N = :meth:`sides`, a multiple of 8, so the rays through the cell's corners are
        among them): a dot cell is a fan of N triangles (the inscribed N-gon, dot colour) plus N quads from the
        polygon to the cell's edge (sheet colour); a margin cell is one fan. Neighbouring cells put the same
        vertices on their shared edge, so the mesh is watertight.
        """
        n_sides = self.sides()
        nx, ny = self.pattern_size
        m, p = self.margin_pitches, self.pitch_mm
        theta = 2.0 * np.pi * np.arange(n_sides) / n_sides
        direction = np.stack([np.cos(theta), np.sin(theta)], axis=1)
        circle = self.radius_mm * direction
        edge = 0.5 * p * direction / np.max(np.abs(direction), axis=1, keepdims=True)
        k = np.arange(n_sides)
        k1 = (k + 1) % n_sides
        dot_uv, sheet_uv = (DARK_UV, LIGHT_UV) if self.dark_dots else (LIGHT_UV, DARK_UV)
        # One dot cell, vertices: 0 centre, 1..N polygon (dot colour), N+1..2N polygon (sheet), 2N+1..3N edge.
        dot_verts = np.concatenate([np.zeros((1, 2)), circle, circle, edge])
        dot_uvs = np.array([dot_uv] * (n_sides + 1) + [sheet_uv] * (2 * n_sides))
        inner, outer = 1 + n_sides + k, 1 + 2 * n_sides + k
        dot_faces = np.concatenate([
            np.stack([np.zeros_like(k), 1 + k1, 1 + k], axis=1),                       # the dot's fan
            np.stack([inner, outer[k1], outer], axis=1),                                # the ring, two per quad
            np.stack([inner, inner[k1], outer[k1]], axis=1)])
        # One margin cell: centre and edge, a fan in the sheet colour.
        empty_verts = np.concatenate([np.zeros((1, 2)), edge])
        empty_uvs = np.array([sheet_uv] * (n_sides + 1))
        empty_faces = np.stack([np.zeros_like(k), 1 + k1, 1 + k], axis=1)
        verts, faces, uvs, count = [], [], [], 0
        for i in range(-m, ny + m):
            for j in range(-m, nx + m):
                is_dot = 0 <= i < ny and 0 <= j < nx
                v, f, u = (dot_verts, dot_faces, dot_uvs) if is_dot else (empty_verts, empty_faces, empty_uvs)
                verts.append(v + [j * p, i * p])
                faces.append(f + count)
                uvs.append(u)
                count += len(v)
        verts = np.concatenate(verts)
        verts = np.concatenate([verts, np.zeros((len(verts), 1))], axis=1)
        texture = np.array([[self.dark, self.light]], dtype=np.float32)
        return verts, np.concatenate(faces), np.concatenate(uvs).astype(float), texture

    def surface(self, R_world_from_board: np.ndarray, t_world_from_board_mm: np.ndarray) -> TexturedSurface:
        """The sheet as an emissive textured mesh placed in the world, ``X_world = R X_board + t``
        (:meth:`board_mesh`; the ``uv`` truth channel of a render codes the colour, not a sheet position)."""
        R = np.asarray(R_world_from_board, dtype=float)
        t = np.asarray(t_world_from_board_mm, dtype=float).reshape(3)
        verts, faces, uv, texture = self.board_mesh()
        return TexturedSurface(vertices_mm=verts @ R.T + t, faces=faces, uv=uv, texture=texture, filter="nearest")
