"""The paper's printed checkerboard calibration target as an exact, textured plane, with optional imperfections.

The other targets build on it: ChArUco boards (:class:`scenes.surfaces.charuco.CharucoBoard`, a checkerboard
with ArUco markers in its white squares, same truth corners and imperfections) and symmetric dot grids
(:class:`scenes.surfaces.dot_grid.DotGrid`, truth points at the dot centres, exact polygon mesh). All three offer
what the renderer uses: ``surface(R, t)``, ``board_mesh()``, ``texture()``,
``radiance_at``/``is_dark``, ``corners_board_mm()``/``true_corners_board_mm()`` and ``extent_board_mm()``.

Board frame (mm): origin at the first inner corner, x along a row of corners, y along a column, z into the
board (a camera looking at the printed face sees it along +z, as OpenCV's calibration object). Each square
is one texel of a nearest-neighbour texture, so the square edges are mathematically sharp and the rendered
pixels are the exact area integrals of the printed pattern (up to Monte-Carlo sampling).

Imperfections (truth side, each off by default; DESIGN.md §7 "calibration-target print scale and flatness")
------------------------------------------------------------------------------------------------------------
A real board is a sheet printed on a laser or inkjet printer and glued to cardboard (the paper's target).
The instrument only ever knows the nominal geometry :meth:`Checkerboard.corners_board_mm`; where the corners
really are is :meth:`Checkerboard.true_corners_board_mm`. The true geometry is built in three steps:

1. **Print** (flat sheet coordinates, mm, same axes and origin as the board frame): every printed square
   corner sits at ``(1 + print_scale_error) * nominal`` (the sheet scales about the first inner corner, the
   board-frame origin), and each *inner* corner is further moved by i.i.d. Gaussian noise
   (``corner_noise_mm`` per axis). The outline of the checkered area and the sheet edge are only scaled: they
   are not X-corners a detector sees, and keeping them straight keeps the white quiet zone intact.
   Between its four corners every printed square edge is a straight line on the flat sheet.
2. **Bend** (:meth:`Checkerboard.sheet_to_board_mm`): the sheet is bent onto the bowed cardboard without
   stretching: a point keeps its arc length from the centre of the checkered area (see ``bow_sag_mm``).
3. **Render**: when any imperfection is on, :meth:`Checkerboard.surface` is a triangle mesh in which each
   square is its own patch of facets whose vertices lie on the true (printed, bent) square, all of its texture
   coordinates pointing at the centre of one texel of a 2-texel (black, white) nearest-filter texture, so the
   black/white edges run exactly along the true square edges (to the facet error, < 0.1 µm by default).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scenes._checks import finite_number, is_int
from scenes.surfaces.textured_surface import TexturedSurface

#: Bound on the distance between the bowed mesh and the analytic bowed surface that the automatic
#: ``bow_subdivisions`` guarantees, mm: half of the 0.1 µm the tests claim, a margin for cells that the corner
#: noise makes slightly non-rectangular (their facets' circumradius grows by ~2 noise/square, < 10 %).
FACET_TOLERANCE_MM = 5e-5

#: Texture of an imperfect board's mesh: one black and one white texel; uv of their centres (nearest filter).
DARK_UV, LIGHT_UV = (0.25, 0.5), (0.75, 0.5)

#: Largest sag accepted, as a fraction of the bowed span (a 10 % sag is far beyond any usable target; it also
#: bounds the automatic subdivision, i.e. the mesh size).
_MAX_SAG_FRACTION = 0.1

#: Largest corner noise accepted, as a fraction of ``square_mm``: at 5 sigma two neighbouring corners still
#: cannot meet, so no printed square folds over.
_MAX_NOISE_FRACTION = 0.05


def parabola_arc_length_mm(d_mm: np.ndarray, k: float) -> np.ndarray:
    """Arc length of ``z = k d^2 / 2`` from its vertex to abscissa ``d`` (signed, odd in d), mm.

    ``s(d) = (d sqrt(1 + k^2 d^2) + asinh(k d) / k) / 2``, the closed form of the integral of
    ``sqrt(1 + z'^2)``; ``k`` (1/mm) is the curvature at the vertex.
    """
    d = np.asarray(d_mm, dtype=float)
    if k == 0.0:
        return d.copy()
    kd = k * d
    return 0.5 * (d * np.sqrt(1.0 + kd * kd) + np.arcsinh(kd) / k)


def parabola_abscissa_mm(s_mm: np.ndarray, k: float) -> np.ndarray:
    """Abscissa ``d`` at which the arc length of ``z = k d^2 / 2`` from its vertex is ``s`` (inverse of
    :func:`parabola_arc_length_mm`), by Newton's method, to ~1e-14 relative.

    Newton starts at ``d = s`` (the arc is never shorter than its projection, so ``|d| <= |s|``) and, ``s(d)``
    being convex for d > 0, decreases monotonically onto the root: no bracketing needed.
    """
    s = np.asarray(s_mm, dtype=float)
    d = s.copy()
    if k == 0.0:
        return d
    for _ in range(100):
        step = (parabola_arc_length_mm(d, k) - s) / np.sqrt(1.0 + (k * d) ** 2)
        d -= step
        if np.all(np.abs(step) <= 1e-15 * np.maximum(1.0, np.abs(s))):
            break
    return d


@dataclass(frozen=True)
class Checkerboard:
    """A printed checkerboard, perfect by default.

    Parameters
    ----------
    squares : (columns, rows)
        Number of squares, 12 x 9 in the paper (11 x 8 inner corners).
    square_mm : float
        Nominal edge of one square, 5 mm in the paper: what the instrument believes.
    margin_squares : int
        White border around the squares, in squares (detectors need a quiet zone).
    dark, light : float
        Emitted radiance of the black and white print (the exposure maps radiance to grey levels).
    print_scale_error : float, dimensionless
        Relative size error of the print: 0.005 makes every printed distance 0.5 % longer than nominal. The
        sheet scales about the first inner corner (the board-frame origin). Typical: 0.1-0.5 % (printer driver
        "fit to page" scaling, paper shrinkage or growth with humidity), which is why calibration guides tell
        you to measure the printed squares (Bouguet, Camera Calibration Toolbox for Matlab, documentation;
        iDICs, A Good Practices Guide for Digital Image Correlation, 2018, calibration section). Must satisfy
        ``|print_scale_error| < 0.5``.
    bow_sag_mm : float, mm
        Out-of-plane bow of the cardboard: the height of the centre of the checkered area above its edges.
        **Positive sag bulges toward the camera, i.e. toward -z_board** (z points into the board). Parabolic
        profile, with ``(xc, yc)`` the centre and ``Lx, Ly`` the nominal size of the checkered area (squares
        only, no margin): for ``bow_axis="y"`` ``z_board(x) = -sag (1 - (2 (x - xc) / Lx)^2)``, zero at the
        checkered area's left and right edges (the profile continues over the margin). Typical: 0.1-2 mm over
        100 mm for printed paper on cardboard; Zhang (2000, IEEE TPAMI 22(11), §5.3) studied cylindrical and
        spherical non-planarity of the pattern. Must not exceed 10 % of the bowed span.
    bow_axis : "y" (default), "x" or "sphere"
        "y": a cylindrical bow about an axis parallel to the board's y axis (z varies with x, span Lx);
        "x": about an axis parallel to x (z varies with y, span Ly, ``Lx -> Ly`` above); "sphere": a
        paraboloid of revolution ``z_board = -sag (1 - r^2 / h^2)``, r the distance from the centre, h half
        the diagonal of the checkered area (sag relative to its four outer corners).
        Paper is inextensible: on the cylinders every point keeps its arc length from the centre line
        (exact: bending without stretching). A sheet cannot cover a doubly curved surface without stretching
        (Gauss), so on the "sphere" each point keeps its geodesic distance from the centre along its
        meridian; lengths around the centre then shrink by ~(k r)^2 / 6 relative (k = 2 sag / h^2; 0.2 % at
        the outer corners for 2 mm over the paper's 60 mm x 45 mm), as a real dished board would have to.
    bow_subdivisions : int or None
        Facets per square edge of a bowed board's mesh (both directions). None: the smallest number that keeps
        the mesh within ``FACET_TOLERANCE_MM`` (0.05 µm) of the analytic surface (see :meth:`subdivisions`);
        24 for 2 mm sag over the paper's board.
    corner_noise_mm : float, mm
        Standard deviation, per in-plane axis, of the i.i.d. Gaussian placement error of every printed inner
        corner (outer corners stay on the scaled outline). Typical: 5-30 µm for laser/inkjet printers
        (addressing at 600-1200 dpi, i.e. 21-42 µm dots, plus paper feed jitter). ``0 <= corner_noise_mm <=
        0.05 square_mm``.
    corner_noise_seed : int
        Seed of the corner noise (``numpy.random.default_rng``), >= 0: same seed, same board.

    Notes
    -----
    ``is_dark``, ``radiance_at`` and ``texture`` always describe the *nominal* (perfect, flat) print, in the
    board frame: they are the pattern model an instrument would fit. The truth of an imperfect board is
    :meth:`true_corners_board_mm` and the mesh of :meth:`surface`.
    """

    squares: tuple[int, int] = (12, 9)
    square_mm: float = 5.0
    margin_squares: int = 1
    dark: float = 0.1
    light: float = 0.9
    print_scale_error: float = 0.0
    bow_sag_mm: float = 0.0
    bow_axis: str = "y"
    bow_subdivisions: int | None = None
    corner_noise_mm: float = 0.0
    corner_noise_seed: int = 0

    def __post_init__(self):
        if self.squares[0] < 3 or self.squares[1] < 3:
            raise ValueError(f"a checkerboard needs at least 3 x 3 squares, got {self.squares}")
        if not self.square_mm > 0:
            raise ValueError(f"square_mm must be positive, got {self.square_mm}")
        self._check_imperfections()

    def _check_imperfections(self) -> None:
        e = finite_number("print_scale_error", self.print_scale_error)
        if not abs(e) < 0.5:
            raise ValueError(f"print_scale_error must satisfy |print_scale_error| < 0.5, got {e}")
        if self.bow_axis not in ("x", "y", "sphere"):
            raise ValueError(f"bow_axis must be 'x', 'y' or 'sphere', got {self.bow_axis!r}")
        sag = finite_number("bow_sag_mm", self.bow_sag_mm)
        span = 2.0 * self._bow_half_span_mm()
        if abs(sag) > _MAX_SAG_FRACTION * span:
            raise ValueError(f"bow_sag_mm must be at most {_MAX_SAG_FRACTION:.0%} of the bowed span "
                             f"({span:g} mm), got {sag}")
        if self.bow_subdivisions is not None and not (is_int(self.bow_subdivisions) and self.bow_subdivisions >= 1):
            raise ValueError(f"bow_subdivisions must be None or an integer >= 1, got {self.bow_subdivisions!r}")
        noise = finite_number("corner_noise_mm", self.corner_noise_mm)
        if noise < 0:
            raise ValueError(f"corner_noise_mm must be >= 0, got {noise}")
        if noise > _MAX_NOISE_FRACTION * self.square_mm:
            raise ValueError(f"corner_noise_mm must be at most {_MAX_NOISE_FRACTION} square_mm "
                             f"({_MAX_NOISE_FRACTION * self.square_mm:g} mm) or squares fold over, got {noise}")
        if not (is_int(self.corner_noise_seed) and self.corner_noise_seed >= 0):
            raise ValueError(f"corner_noise_seed must be an integer >= 0, got {self.corner_noise_seed!r}")

    # --------------------------------------------------------------------------------------------------------
    # Nominal geometry: what the instrument believes
    @property
    def inner_corners(self) -> tuple[int, int]:
        """(columns, rows) of inner corners, OpenCV's ``patternSize``."""
        return self.squares[0] - 1, self.squares[1] - 1

    @property
    def is_perfect(self) -> bool:
        """True when no imperfection is on (the board renders as the single exact quad)."""
        return self.print_scale_error == 0 and self.bow_sag_mm == 0 and self.corner_noise_mm == 0

    def corners_board_mm(self) -> np.ndarray:
        """Nominal inner corners in the board frame, row by row (x fastest), shape (N, 3), mm."""
        nx, ny = self.inner_corners
        jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
        return np.stack([jj.ravel() * self.square_mm, ii.ravel() * self.square_mm, np.zeros(nx * ny)], axis=1)

    def extent_board_mm(self) -> tuple[float, float, float, float]:
        """Nominal (x_min, x_max, y_min, y_max) of the printed sheet including the margin, mm."""
        m = (1 + self.margin_squares) * self.square_mm
        nx, ny = self.inner_corners
        return -m, (nx - 1) * self.square_mm + m, -m, (ny - 1) * self.square_mm + m

    def checkered_extent_board_mm(self) -> tuple[float, float, float, float]:
        """Nominal (x_min, x_max, y_min, y_max) of the checkered area (squares only, no margin), mm."""
        nx, ny = self.inner_corners
        return -self.square_mm, nx * self.square_mm, -self.square_mm, ny * self.square_mm

    def is_dark(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """True where nominal board point (x, y) is printed black: the square left-above the origin is black."""
        col = np.floor(np.asarray(x_mm) / self.square_mm)
        row = np.floor(np.asarray(y_mm) / self.square_mm)
        x0, x1, y0, y1 = self.extent_board_mm()
        inside = ((x_mm >= x0 + self.margin_squares * self.square_mm) & (x_mm < x1 - self.margin_squares * self.square_mm)
                  & (y_mm >= y0 + self.margin_squares * self.square_mm) & (y_mm < y1 - self.margin_squares * self.square_mm))
        return inside & ((col + row) % 2 == 0)

    def texture(self) -> np.ndarray:
        """Nominal print, one texel per square including the margin, row 0 at y_min, shape (rows, cols), radiance."""
        x0, x1, y0, y1 = self.extent_board_mm()
        cols = int(round((x1 - x0) / self.square_mm))
        rows = int(round((y1 - y0) / self.square_mm))
        xc = x0 + (np.arange(cols) + 0.5) * self.square_mm
        yc = y0 + (np.arange(rows) + 0.5) * self.square_mm
        X, Y = np.meshgrid(xc, yc)
        return np.where(self.is_dark(X, Y), self.dark, self.light).astype(np.float32)

    def radiance_at(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Nominal printed radiance at board points (off the sheet: 0, the black background)."""
        x0, x1, y0, y1 = self.extent_board_mm()
        on_sheet = (x_mm >= x0) & (x_mm < x1) & (y_mm >= y0) & (y_mm < y1)
        return np.where(on_sheet, np.where(self.is_dark(x_mm, y_mm), self.dark, self.light), 0.0)

    # --------------------------------------------------------------------------------------------------------
    # True geometry: print (scale, corner noise), then bend
    def printed_grid_sheet_mm(self) -> np.ndarray:
        """Where the printer put every square corner, on the flat sheet, shape (rows + 1, cols + 1, 2), mm.

        ``rows, cols`` count the squares including the margin (a :class:`Checkerboard`'s ``texture().shape``);
        entry ``[i, j]`` is the corner between squares ``(i-1, j-1)`` and ``(i, j)``, nominally at
        ``(x_min + j s, y_min + i s)``.
        Flat sheet coordinates share the board frame's axes and origin (they are the board frame of the
        unbent sheet).
        """
        x0, _, y0, _ = self.extent_board_mm()
        rows, cols = self.squares[1] + 2 * self.margin_squares, self.squares[0] + 2 * self.margin_squares
        X, Y = np.meshgrid(x0 + np.arange(cols + 1) * self.square_mm, y0 + np.arange(rows + 1) * self.square_mm)
        grid = np.stack([X, Y], axis=-1) * (1.0 + self.print_scale_error)
        if self.corner_noise_mm > 0:
            # The inner corners are the grid points strictly inside the checkered area; one draw per corner
            # and axis, in corners_board_mm() order (row by row, x fastest), so corner k gets draw k.
            nx, ny = self.inner_corners
            m = self.margin_squares + 1
            rng = np.random.default_rng(self.corner_noise_seed)
            grid[m:m + ny, m:m + nx] += rng.normal(0.0, self.corner_noise_mm, size=(ny, nx, 2))
        return grid

    def _bow_half_span_mm(self) -> float:
        """Half of the span the sag is measured over: Lx/2, Ly/2 or half the diagonal (mm)."""
        x0, x1, y0, y1 = self.checkered_extent_board_mm()
        if self.bow_axis == "y":
            return 0.5 * (x1 - x0)
        if self.bow_axis == "x":
            return 0.5 * (y1 - y0)
        return 0.5 * math.hypot(x1 - x0, y1 - y0)

    def bow_curvature_per_mm(self) -> float:
        """Curvature of the bow's profile at the centre, ``2 |sag| / h^2`` (1/mm): its largest anywhere."""
        return 2.0 * abs(self.bow_sag_mm) / self._bow_half_span_mm() ** 2

    def sheet_to_board_mm(self, sheet_xy_mm: np.ndarray) -> np.ndarray:
        """Bend flat-sheet points onto the bowed board, preserving arc length from the centre, (N, 2) -> (N, 3) mm.

        With no bow this is ``(x, y, 0)``. Otherwise, with ``(xc, yc)`` the nominal centre of the checkered
        area and ``d`` the signed in-plane offset from it along the bowed direction (radially for "sphere"),
        the bent point is at the abscissa whose parabola arc length from the centre equals ``d`` (Newton,
        :func:`parabola_abscissa_mm`), at height ``z = -sag (1 - (abscissa / h)^2)``.
        """
        p = np.asarray(sheet_xy_mm, dtype=float).reshape(-1, 2)
        out = np.concatenate([p, np.zeros((len(p), 1))], axis=1)
        if self.bow_sag_mm == 0:
            return out
        x0, x1, y0, y1 = self.checkered_extent_board_mm()
        centre = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
        h, k = self._bow_half_span_mm(), self.bow_curvature_per_mm()
        if self.bow_axis in ("x", "y"):
            a = 0 if self.bow_axis == "y" else 1            # the in-plane axis the height varies along
            d = parabola_abscissa_mm(p[:, a] - centre[a], k)
            out[:, a] = centre[a] + d
            r2 = d * d
        else:
            rho = np.linalg.norm(p - centre, axis=1)
            r = parabola_abscissa_mm(rho, k)
            with np.errstate(invalid="ignore", divide="ignore"):
                shrink = np.where(rho > 0, r / rho, 1.0)    # the centre itself does not move
            out[:, :2] = centre + (p - centre) * shrink[:, None]
            r2 = r * r
        out[:, 2] = -self.bow_sag_mm * (1.0 - r2 / (h * h))
        return out

    def true_corners_board_mm(self) -> np.ndarray:
        """Where the inner corners really are (all imperfections), board frame, same order as
        :meth:`corners_board_mm`, shape (N, 3), mm."""
        nx, ny = self.inner_corners
        m = self.margin_squares + 1
        printed = self.printed_grid_sheet_mm()[m:m + ny, m:m + nx].reshape(-1, 2)
        return self.sheet_to_board_mm(printed)

    def subdivisions(self) -> int:
        """Facets per square edge of the mesh: ``bow_subdivisions``, or the automatic number.

        Automatic: 1 when flat. Bowed: the height is quadratic in (x, y) with Hessian eigenvalues at most
        ``k = 2 |sag| / h^2``, so on a facet with circumradius R (of its projection on the board plane) the
        linear interpolant is off by at most ``k R^2 / 2`` (the error at a point is
        ``1/2 sum_i lambda_i (v_i - p)^T H (v_i - p)`` and ``sum_i lambda_i |v_i - p|^2 <= R^2``). Facets are
        the halves of sub-squares, R ~ half their diagonal ``D / n`` (D: longest printed square diagonal; the
        bend only shortens in-plane lengths), so ``n = ceil(sqrt(k D^2 / (8 FACET_TOLERANCE_MM)))``.
        """
        if self.bow_subdivisions is not None:
            return int(self.bow_subdivisions)
        if self.bow_sag_mm == 0:
            return 1
        g = self.printed_grid_sheet_mm()
        diagonals = np.concatenate([np.linalg.norm(g[1:, 1:] - g[:-1, :-1], axis=-1).ravel(),
                                    np.linalg.norm(g[1:, :-1] - g[:-1, 1:], axis=-1).ravel()])
        n = math.sqrt(self.bow_curvature_per_mm() * diagonals.max() ** 2 / (8.0 * FACET_TOLERANCE_MM))
        return max(1, math.ceil(n))

    # --------------------------------------------------------------------------------------------------------
    # Rendering
    def surface(self, R_world_from_board: np.ndarray, t_world_from_board_mm: np.ndarray) -> TexturedSurface:
        """The sheet as an emissive textured mesh placed in the world, ``X_world = R X_board + t``.

        Perfect board: one quad with the one-texel-per-square texture. Imperfect board: the mesh of
        :meth:`board_mesh`, each square its own patch of facets on the true square; its texture coordinates
        only pick a colour, so a render's ``uv`` truth channel then codes black/white, not a sheet position
        (the ``position_world_mm`` channel is the true bowed surface).
        """
        R = np.asarray(R_world_from_board, dtype=float)
        t = np.asarray(t_world_from_board_mm, dtype=float).reshape(3)
        if not self.is_perfect:
            verts, faces, uv, texture = self.board_mesh()
            return TexturedSurface(vertices_mm=verts @ R.T + t, faces=faces, uv=uv, texture=texture,
                                   filter="nearest")
        x0, x1, y0, y1 = self.extent_board_mm()
        corners = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], dtype=float)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
        # Winding so that the face normal is -z_board: the printed side faces the camera.
        faces = np.array([[0, 2, 1], [0, 3, 2]])
        verts = corners @ R.T + t
        return TexturedSurface(vertices_mm=verts, faces=faces, uv=uv, texture=self.texture(), filter="nearest")

    def board_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The true sheet as a triangle mesh in the board frame (any board, perfect or not).

        Returns
        -------
        vertices_mm : (V, 3) float, board frame, mm; ``(n + 1)^2`` per square, n = :meth:`subdivisions`
        faces : (F, 3) int, ``2 n^2`` per square, face normals toward -z_board (the printed side)
        uv : (V, 2) float, constant per square: the centre of its texel in ``texture`` (a :class:`CharucoBoard`:
            the square's block of its full texture, interpolated over the patch)
        texture : (1, 2) float32, radiance ``[[dark, light]]`` (a :class:`CharucoBoard`: :meth:`texture`)

        Squares are patches of their own (no shared vertices) so that each can have one colour; vertices on
        a shared edge are copies of the same bent point, so the mesh is watertight.
        """
        n = self.subdivisions()
        grid = self.printed_grid_sheet_mm()
        rows, cols = grid.shape[0] - 1, grid.shape[1] - 1
        fine = self.sheet_to_board_mm(_refine(grid, n).reshape(-1, 2)).reshape(rows * n + 1, cols * n + 1, 3)
        # Each square's (n+1) x (n+1) block of the fine grid, as (rows, cols, n+1, n+1, 3).
        a = np.arange(n + 1)
        ii = np.arange(rows)[:, None, None, None] * n + a[None, None, :, None]
        jj = np.arange(cols)[None, :, None, None] * n + a[None, None, None, :]
        verts = fine[ii, jj].reshape(-1, 3)
        uv, texture = self._square_patch_uv(rows, cols, n)
        faces = _grid_faces(n)[None] + (np.arange(rows * cols) * (n + 1) ** 2)[:, None, None]
        return verts, faces.reshape(-1, 3), uv, texture

    def _square_patch_uv(self, rows: int, cols: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Texture coordinates of the mesh's square patches and the texture they point into.

        Returns ``uv`` of shape (rows * cols * (n + 1)^2, 2), in the vertex order of :meth:`board_mesh` (square
        by square, row by row; inside a square its (n + 1) x (n + 1) block, x fastest), and the texture. Here:
        one colour per square, from the nominal pattern at its nominal centre, into a (1, 2) [dark, light]
        texture.
        """
        x0, _, y0, _ = self.extent_board_mm()
        xc, yc = np.meshgrid(x0 + (np.arange(cols) + 0.5) * self.square_mm, y0 + (np.arange(rows) + 0.5) * self.square_mm)
        dark = self.is_dark(xc, yc).ravel()
        uv = np.repeat(np.where(dark[:, None], DARK_UV, LIGHT_UV), (n + 1) ** 2, axis=0)
        return uv, np.array([[self.dark, self.light]], dtype=np.float32)


def _refine(grid: np.ndarray, n: int) -> np.ndarray:
    """Subdivide every cell of a (R+1, C+1, 2) corner grid into n x n by bilinear interpolation of its four
    corners, shape (R n + 1, C n + 1, 2). A point on an edge shared by two cells depends only on that edge's
    two corners (bilinear is linear along an edge), so it is computed once for both."""
    rows, cols = grid.shape[0] - 1, grid.shape[1] - 1

    def split(count):
        index = np.arange(count * n + 1)
        cell = np.minimum(index // n, count - 1)
        return cell, (index - cell * n) / n

    ci, fi = split(rows)
    cj, fj = split(cols)
    fi, fj = fi[:, None, None], fj[None, :, None]
    I, J = ci[:, None], cj[None, :]
    return ((1 - fi) * (1 - fj) * grid[I, J] + (1 - fi) * fj * grid[I, J + 1]
            + fi * (1 - fj) * grid[I + 1, J] + fi * fj * grid[I + 1, J + 1])


def _grid_faces(n: int) -> np.ndarray:
    """Triangles of an (n+1) x (n+1) vertex block (index ``i (n+1) + j``, j along x), shape (2 n^2, 3).

    Same winding as the perfect board's quad, ``(v00, v11, v10)`` and ``(v00, v01, v11)``: face normal -z_board.
    """
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = (i * (n + 1) + j).ravel()
    v10, v01, v11 = v00 + 1, v00 + n + 1, v00 + n + 2
    return np.concatenate([np.stack([v00, v11, v10], axis=1), np.stack([v00, v01, v11], axis=1)])
