"""Surface strain from stereo-DIC point grids: triangular Cosserat point elements and a strain window.

Input is what the instrument measures: the triangulated 3-D positions of a regular grid of points of interest
in the reference and in the deformed state, ``X_ref_mm`` and ``X_def_mm``, arrays of shape (rows, cols, 3) in
mm (row ``i``, column ``j`` of the grid; the grid comes from a regular step in the left camera image, so
neighbouring grid points are neighbours on the surface). A point with a non-finite coordinate in either state
was not measured (a hole) and is not used.

Two methods, one entry point :func:`surface_strain`:

* **Triangles** (``window=None``), as in the paper and MultiDIC (Solav et al. 2014, triangular Cosserat point
  elements): the grid is split into two triangles per cell (:func:`triangulate_grid`); each triangle gets the
  surface deformation gradient ``F = [d1 d2 n][D1 D2 N]^-1`` that maps its reference plane onto its deformed
  plane (edge vectors ``D1, D2 -> d1, d2``, unit normal ``N -> n``), hence its Green-Lagrange strain and its
  area ratio; nodes get the area-weighted average of their valid triangles.
* **Strain window** (``window=k``): at each node the displacement over the k x k neighbourhood of valid grid
  points is fitted by least squares (first or second order) in tangent-plane coordinates, and the strain is
  formed from the fitted derivatives at the node.

Conventions
-----------
Local frame ``(e1, e2, n)``, right-handed and orthonormal, attached to the *reference* surface:

* ``n`` is the reference surface normal, oriented with the grid: along ``dX/dj x dX/di`` (increasing column
  index x increasing row index). For a grid laid out like the left image (columns to the right, rows
  downwards) ``n`` therefore points away from the left camera, into the specimen.
* ``e1`` is the unit projection onto the tangent plane of a reference direction: by default the mean grid
  direction along increasing column index, ``nanmean(X_ref[:, j+1] - X_ref[:, j])``, normalised; the caller
  may pass ``direction_mm`` (3,) instead. Where the direction is (nearly) along ``n`` the frame, and with it
  the strain, is NaN.
* ``e2 = n x e1``; for the default direction it is close to the increasing-row direction.

Strain ``E = 1/2 (F^T F - I)`` (Green-Lagrange) restricted to the tangent plane, as a 2 x 2 tensor with
components ``E11, E22, E12`` in ``(e1, e2)``; dimensionless. Undefined values are NaN, never a wrong number.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import correlate1d

#: Gauge, in grid points per side, of the triangle method: one triangle spans one grid cell (2 x 2 points).
TRIANGLE_GAUGE_WINDOW = 2

#: A triangle whose edge vectors enclose an angle with ``|sin| <= DEGENERATE_SINE`` (in the reference or in
#: the deformed state) is degenerate: its plane, hence its strain, is undefined (NaN).
DEGENERATE_SINE = 1e-8

#: The reference direction projected onto a tangent plane must keep at least this fraction of its length,
#: else e1 is undefined there (the direction is along the normal) and the node or triangle is NaN.
DIRECTION_TOL = 1e-6

#: Window points whose second in-plane variance is below this fraction of the first are (nearly) collinear.
COLLINEAR_TOL = 1e-10

#: The normal equations of a window fit (in scaled coordinates) whose smallest eigenvalue is below this
#: fraction of the largest are treated as singular (e.g. quadratic fit to points on two lines).
CONDITION_TOL = 1e-10

_FITS = ("linear", "quadratic")


@dataclass(frozen=True)
class TriangleStrain:
    """Strain of each triangle of the grid (output of :func:`triangle_strain`).

    All per-triangle arrays are NaN for a triangle that has a vertex not measured in either state, or that
    is degenerate (see :data:`DEGENERATE_SINE`) in either state.

    Attributes
    ----------
    triangles : ndarray of int, shape (n_tri, 3)
        Vertex indices into the flattened grid (``i * cols + j``), as from :func:`triangulate_grid`.
    F : ndarray, shape (n_tri, 3, 3)
        Cosserat-point deformation gradient ``[d1 d2 n][D1 D2 N]^-1`` in the frame of the points.
    E11, E22, E12 : ndarray, shape (n_tri,)
        Green-Lagrange strain in the triangle's frame ``(e1, e2)``.
    E1, E2 : ndarray, shape (n_tri,)
        Principal strains, ``E1 >= E2``.
    angle_deg : ndarray, shape (n_tri,), degrees
        Angle of the ``E1`` direction from ``e1`` towards ``e2``, in (-90, 90]; arbitrary where ``E1 == E2``.
    magnitude : ndarray, shape (n_tri,)
        Lagrangian strain magnitude ``sqrt(E1**2 + E2**2)`` (Frobenius norm of E; MultiDIC's ``Emgn``).
    area_ref_mm2, area_def_mm2 : ndarray, shape (n_tri,), mm^2
        Triangle areas in the reference and deformed states.
    area_change : ndarray, shape (n_tri,)
        ``J - 1`` with ``J = A_def / A_ref`` (= det F).
    e1, e2, n : ndarray, shape (n_tri, 3)
        The triangle's reference frame (unit vectors).
    """

    triangles: np.ndarray
    F: np.ndarray
    E11: np.ndarray
    E22: np.ndarray
    E12: np.ndarray
    E1: np.ndarray
    E2: np.ndarray
    angle_deg: np.ndarray
    magnitude: np.ndarray
    area_ref_mm2: np.ndarray
    area_def_mm2: np.ndarray
    area_change: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    n: np.ndarray


@dataclass(frozen=True)
class SurfaceStrain:
    """Nodal surface strain on the grid (output of :func:`surface_strain`).

    Every array of shape (rows, cols[, 3]) is NaN where the strain is undefined (node not measured, no valid
    adjacent triangle, too few or collinear window points, e1 undefined).

    Attributes
    ----------
    E11, E22, E12 : ndarray, shape (rows, cols)
        Green-Lagrange strain in the node's frame ``(e1, e2)``, dimensionless.
    E1, E2 : ndarray, shape (rows, cols)
        Principal strains, ``E1 >= E2``.
    angle_deg : ndarray, shape (rows, cols), degrees
        Angle of the ``E1`` direction from ``e1`` towards ``e2``, in (-90, 90]; arbitrary where ``E1 == E2``.
    magnitude : ndarray, shape (rows, cols)
        Lagrangian strain magnitude ``sqrt(E1**2 + E2**2)``: the Frobenius norm of the 2 x 2 E. MultiDIC's
        ``Emgn`` is ``norm(E, 'fro')`` of its 3 x 3 Cosserat E; since ``F N = n`` that E has no normal
        components, so the two are the same number.
    area_change : ndarray, shape (rows, cols)
        Relative area change ``J - 1``. Triangles: ``sum A_def / sum A_ref - 1`` over the node's valid
        triangles (their area-weighted mean of ``A_def/A_ref - 1``). Window: ``sqrt(det(I + 2E)) - 1``.
    e1, e2, n : ndarray, shape (rows, cols, 3)
        The node's reference frame (unit vectors, right-handed).
    method : str
        ``"triangle"`` or ``"window"``.
    window : int
        Gauge in grid points per side: the window ``k``, or :data:`TRIANGLE_GAUGE_WINDOW` (2) for triangles.
        Use with :func:`virtual_strain_gauge_px`.
    fit : str or None
        ``"linear"`` / ``"quadratic"`` for the window method, None for triangles.
    triangles : TriangleStrain or None
        The per-triangle values the nodal ones were averaged from (triangle method only).
    """

    E11: np.ndarray
    E22: np.ndarray
    E12: np.ndarray
    E1: np.ndarray
    E2: np.ndarray
    angle_deg: np.ndarray
    magnitude: np.ndarray
    area_change: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    n: np.ndarray
    method: str
    window: int
    fit: str | None
    triangles: TriangleStrain | None = None


# ---------------------------------------------------------------------------------------------------------
# Grid, gauge, argument checks
# ---------------------------------------------------------------------------------------------------------

def triangulate_grid(rows: int, cols: int) -> np.ndarray:
    """Two triangles per cell of a rows x cols grid.

    Cell ``(i, j)`` (corners ``a = (i, j)``, ``b = (i, j+1)``, ``c = (i+1, j)``, ``d = (i+1, j+1)``) is split
    along its diagonal ``a-d`` into ``(a, b, d)`` and ``(a, d, c)``. With this vertex order both triangles'
    ``(V1 - V0) x (V2 - V0)`` point along ``dX/dj x dX/di`` (the grid orientation of the module docstring).

    Parameters
    ----------
    rows, cols : int
        Grid size, each at least 2.

    Returns
    -------
    ndarray of int, shape (2 (rows-1) (cols-1), 3)
        Vertex indices into the flattened grid (``i * cols + j``), cells in row-major order, ``(a, b, d)``
        before ``(a, d, c)`` in each cell.
    """
    for name, value in (("rows", rows), ("cols", cols)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 2:
            raise ValueError(f"{name} must be an integer >= 2, got {value!r}")
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (i * cols + j).ravel()
    b, c = a + 1, a + cols
    d = c + 1
    return np.stack([np.stack([a, b, d], -1), np.stack([a, d, c], -1)], axis=1).reshape(-1, 3)


def virtual_strain_gauge_px(window: int, step_px: float, subset_px: float) -> float:
    """Virtual strain gauge size in the image, px: ``(window - 1) * step_px + subset_px``.

    A strain value at a node depends on the displacements of the grid points of its window, which span
    ``(window - 1)`` grid steps; each of those displacements is itself measured from a subset of
    ``subset_px`` pixels centred on its point, so the image region that influences one strain value is
    ``(window - 1) * step + subset`` pixels wide (the usual "virtual strain gauge", e.g. the iDICs Good
    Practices Guide). For the triangle method use ``window = 2`` (:data:`TRIANGLE_GAUGE_WINDOW`): one triangle
    spans one grid cell. The nodal values of the triangle method average the triangles of the cells around a
    node, which reach one step further (a 3-point span), so 2 is the gauge of the per-triangle values.

    Parameters
    ----------
    window : int
        Points per side of the strain window (>= 2).
    step_px : float, px
        Grid step (distance between neighbouring points of interest) in the image; > 0.
    subset_px : float, px
        Subset size (side length); > 0.

    Returns
    -------
    float, px
    """
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 2:
        raise ValueError(f"window must be an integer >= 2, got {window!r}")
    for name, value in (("step_px", step_px), ("subset_px", subset_px)):
        if not (np.isscalar(value) and np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float((window - 1) * step_px + subset_px)


def _check_grids(X_ref_mm, X_def_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Float (rows, cols, 3) grids and the (rows, cols) mask of points measured in both states."""
    X_ref = np.asarray(X_ref_mm, dtype=float)
    if X_ref.ndim != 3 or X_ref.shape[2] != 3 or X_ref.shape[0] < 2 or X_ref.shape[1] < 2:
        raise ValueError(f"X_ref_mm must have shape (rows, cols, 3) with rows, cols >= 2, got {X_ref.shape}")
    X_def = np.asarray(X_def_mm, dtype=float)
    if X_def.shape != X_ref.shape:
        raise ValueError(f"X_def_mm must have the shape of X_ref_mm {X_ref.shape}, got {X_def.shape}")
    valid = np.all(np.isfinite(X_ref), axis=-1) & np.all(np.isfinite(X_def), axis=-1)
    return X_ref, X_def, valid


def _reference_direction(direction_mm, X_ref: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Unit reference direction for e1: ``direction_mm`` or the mean increasing-column grid direction."""
    if direction_mm is not None:
        direction = np.asarray(direction_mm, dtype=float)
        if direction.shape != (3,) or not np.all(np.isfinite(direction)) or not np.linalg.norm(direction) > 0:
            raise ValueError(f"direction_mm must be a finite non-zero vector of shape (3,), got {direction_mm!r}")
    else:
        pair = valid[:, 1:] & valid[:, :-1]
        if not pair.any():
            raise ValueError("no two horizontally adjacent valid points to take the grid direction from; "
                             "pass direction_mm")
        # Mean of the column steps over all measured neighbour pairs: robust to holes, no fit needed.
        direction = (X_ref[:, 1:] - X_ref[:, :-1])[pair].mean(axis=0)
        if not np.linalg.norm(direction) > 0:
            raise ValueError("the mean grid direction along columns is zero; pass direction_mm")
    return direction / np.linalg.norm(direction)


# ---------------------------------------------------------------------------------------------------------
# Small vector helpers on (..., 3) arrays (explicit components: much faster than np.cross / einsum here)
# ---------------------------------------------------------------------------------------------------------

def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _tangent_frame(normal: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``e1`` = unit projection of ``direction`` (3,) onto the planes of unit ``normal`` (..., 3); ``e2 = n x e1``.

    NaN where the projection keeps less than :data:`DIRECTION_TOL` of the direction's length.
    """
    along = direction - _dot(normal, direction)[..., None] * normal
    length = np.linalg.norm(along, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        e1 = np.where(length > DIRECTION_TOL, along / length, np.nan)
    return e1, _cross(normal, e1)


def _principal(E11, E22, E12) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Principal strains E1 >= E2, angle of E1 from e1 (deg, (-90, 90]) and magnitude sqrt(E1^2 + E2^2)."""
    mean = 0.5 * (E11 + E22)
    radius = np.hypot(0.5 * (E11 - E22), E12)
    angle_deg = 0.5 * np.degrees(np.arctan2(2.0 * E12, E11 - E22))
    magnitude = np.sqrt(E11 ** 2 + E22 ** 2 + 2.0 * E12 ** 2)
    return mean + radius, mean - radius, angle_deg, magnitude


# ---------------------------------------------------------------------------------------------------------
# Triangle (Cosserat point element) method
# ---------------------------------------------------------------------------------------------------------

def _triangle_strain(P_ref: np.ndarray, P_def: np.ndarray, valid_point: np.ndarray, triangles: np.ndarray,
                     direction: np.ndarray) -> TriangleStrain:
    """Per-triangle strain for flattened points (N, 3) and triangles (n_tri, 3); see :func:`triangle_strain`."""
    with np.errstate(invalid="ignore", divide="ignore"):
        D1 = P_ref[triangles[:, 1]] - P_ref[triangles[:, 0]]
        D2 = P_ref[triangles[:, 2]] - P_ref[triangles[:, 0]]
        d1 = P_def[triangles[:, 1]] - P_def[triangles[:, 0]]
        d2 = P_def[triangles[:, 2]] - P_def[triangles[:, 0]]
        cross_ref, cross_def = _cross(D1, D2), _cross(d1, d2)
        twice_area_ref = np.linalg.norm(cross_ref, axis=-1)
        twice_area_def = np.linalg.norm(cross_def, axis=-1)
        ok = (valid_point[triangles].all(axis=1)
              & (twice_area_ref > DEGENERATE_SINE * np.linalg.norm(D1, axis=-1) * np.linalg.norm(D2, axis=-1))
              & (twice_area_def > DEGENERATE_SINE * np.linalg.norm(d1, axis=-1) * np.linalg.norm(d2, axis=-1)))
        N = cross_ref / twice_area_ref[:, None]
        n_def = cross_def / twice_area_def[:, None]
        # Reciprocal (dual) basis of (D1, D2, N): D^a . D_b = delta_ab, D^a . N = 0; then
        # F = d1 (x) D^1 + d2 (x) D^2 + n (x) N is [d1 d2 n][D1 D2 N]^-1 without a 3 x 3 inverse.
        R1 = _cross(D2, N) / twice_area_ref[:, None]
        R2 = _cross(N, D1) / twice_area_ref[:, None]
        F = d1[:, :, None] * R1[:, None, :] + d2[:, :, None] * R2[:, None, :] + n_def[:, :, None] * N[:, None, :]
        e1, e2 = _tangent_frame(N, direction)
        # F e_a for in-plane e_a (N . e_a = 0), then E_ab = (F e_a . F e_b - delta_ab) / 2.
        Fe1 = d1 * _dot(R1, e1)[:, None] + d2 * _dot(R2, e1)[:, None]
        Fe2 = d1 * _dot(R1, e2)[:, None] + d2 * _dot(R2, e2)[:, None]
        E11 = 0.5 * (_dot(Fe1, Fe1) - 1.0)
        E22 = 0.5 * (_dot(Fe2, Fe2) - 1.0)
        E12 = 0.5 * _dot(Fe1, Fe2)
        ok &= np.isfinite(E11) & np.isfinite(E22) & np.isfinite(E12)
        J = twice_area_def / twice_area_ref

    def masked(a):
        return np.where(ok.reshape((-1,) + (1,) * (a.ndim - 1)), a, np.nan)

    E11, E22, E12 = masked(E11), masked(E22), masked(E12)
    E1, E2, angle_deg, magnitude = _principal(E11, E22, E12)
    return TriangleStrain(triangles=triangles, F=masked(F), E11=E11, E22=E22, E12=E12, E1=E1, E2=E2,
                          angle_deg=angle_deg, magnitude=magnitude, area_ref_mm2=masked(0.5 * twice_area_ref),
                          area_def_mm2=masked(0.5 * twice_area_def), area_change=masked(J - 1.0),
                          e1=masked(e1), e2=masked(e2), n=masked(N))


def triangle_strain(X_ref_mm, X_def_mm, *, direction_mm=None) -> TriangleStrain:
    """Green-Lagrange strain of every triangle of the grid (triangular Cosserat point elements).

    For each triangle ``(V0, V1, V2)`` of :func:`triangulate_grid`, with edges ``D1 = V1 - V0``,
    ``D2 = V2 - V0`` and unit normal ``N = D1 x D2 / |D1 x D2|`` in the reference state and ``d1, d2, n`` in
    the deformed state, ``F = [d1 d2 n][D1 D2 N]^-1`` maps the reference plane onto the deformed plane
    (``F D_a = d_a``, ``F N = n``). In the triangle's frame ``(e1, e2, N)`` (module docstring) the strain is
    ``E_ab = 1/2 (F e_a . F e_b - delta_ab)``, ``a, b = 1, 2``, and ``J = A_def / A_ref = det F``. The
    triangle is homogeneously deformed, so this is exact for any deformation that is homogeneous over it.

    Parameters
    ----------
    X_ref_mm, X_def_mm : array, shape (rows, cols, 3), mm
        Reference and deformed positions of the grid points; non-finite = not measured.
    direction_mm : array, shape (3,), optional
        Reference direction for e1 (any length); default the mean grid direction along increasing columns.

    Returns
    -------
    TriangleStrain
    """
    X_ref, X_def, valid = _check_grids(X_ref_mm, X_def_mm)
    direction = _reference_direction(direction_mm, X_ref, valid)
    rows, cols = valid.shape
    return _triangle_strain(X_ref.reshape(-1, 3), X_def.reshape(-1, 3), valid.ravel(),
                            triangulate_grid(rows, cols), direction)


def _nodal_from_triangles(tri: TriangleStrain, shape: tuple[int, int], direction: np.ndarray) -> SurfaceStrain:
    """Area-weighted average of the valid adjacent triangles' values at each node."""
    n_nodes = shape[0] * shape[1]
    ok = np.isfinite(tri.E11)
    weight = np.where(ok, tri.area_ref_mm2, 0.0)
    vertex = tri.triangles.ravel()

    def node_sum(values):
        # Each triangle contributes its value to its three vertices.
        values = np.where(ok, values, 0.0)
        return np.bincount(vertex, weights=np.repeat(values, 3), minlength=n_nodes)

    total_weight = node_sum(weight)
    has = total_weight > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        inv_weight = np.where(has, 1.0 / total_weight, np.nan)
        # Node normal: area-weighted mean of the triangle normals (an estimate of the surface normal there).
        normal = _unit(np.stack([node_sum(weight * tri.n[:, k]) for k in range(3)], axis=-1)
                       * inv_weight[:, None])
        e1, e2 = _tangent_frame(normal, direction)
        # Components are averaged as numbers, each triangle's in its own frame: on a flat surface the frames
        # coincide with the node's; on a curved one each frame is e1 = the same direction projected onto the
        # triangle's plane, which keeps e.g. an isotropic strain exactly isotropic.
        E11 = node_sum(weight * tri.E11) * inv_weight
        E22 = node_sum(weight * tri.E22) * inv_weight
        E12 = node_sum(weight * tri.E12) * inv_weight
        # Area-weighted mean of A_def / A_ref - 1 = (sum A_def) / (sum A_ref) - 1 over the valid triangles.
        area_change = node_sum(tri.area_def_mm2) * inv_weight - 1.0
    defined = has & np.all(np.isfinite(e1), axis=-1)

    def grid(a):
        a = np.where(defined.reshape((-1,) + (1,) * (a.ndim - 1)), a, np.nan)
        return a.reshape(shape + a.shape[1:])

    E11, E22, E12 = grid(E11), grid(E22), grid(E12)
    E1, E2, angle_deg, magnitude = _principal(E11, E22, E12)
    return SurfaceStrain(E11=E11, E22=E22, E12=E12, E1=E1, E2=E2, angle_deg=angle_deg, magnitude=magnitude,
                         area_change=grid(area_change), e1=grid(e1), e2=grid(e2), n=grid(normal),
                         method="triangle", window=TRIANGLE_GAUGE_WINDOW, fit=None, triangles=tri)


# ---------------------------------------------------------------------------------------------------------
# Strain-window method
# ---------------------------------------------------------------------------------------------------------

def _window_sums(a: np.ndarray, kernel_rows: np.ndarray, kernel_cols: np.ndarray) -> np.ndarray:
    """``out[i, j] = sum_{di, dj} kernel_rows[di] kernel_cols[dj] a[i + di, j + dj]`` (zero outside the grid).

    Separable, direct (not running) sums: exact weights, no drift along the rows. ``a`` is (rows, cols, ...).
    """
    return correlate1d(correlate1d(a, kernel_rows, axis=0, mode="constant", cval=0.0),
                       kernel_cols, axis=1, mode="constant", cval=0.0)


_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))  # unique entries of a symmetric 3 x 3
_QUAD_EXPONENTS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))  # basis 1, xi, eta, xi^2, xi eta, eta^2


def _symmetric(six: np.ndarray) -> np.ndarray:
    """(..., 6) unique entries in :data:`_SYM` order -> (..., 3, 3)."""
    out = np.empty(six.shape[:-1] + (3, 3))
    for k, (a, b) in enumerate(_SYM):
        out[..., a, b] = out[..., b, a] = six[..., k]
    return out


def _quadratic_fit(Xr: np.ndarray, U: np.ndarray, valid: np.ndarray, cand: np.ndarray, r: int,
                   axes: tuple[np.ndarray, np.ndarray, np.ndarray], low_moment: dict, low_rhs: np.ndarray):
    """Second-order least-squares fit over the window at the candidate nodes.

    Fits ``v(xi, eta) = c0 + c1 xi + c2 eta + c3 xi^2 + c4 xi eta + c5 eta^2`` to ``v = (u_x, u_y, u_z, h)``
    with ``(xi, eta, h) = (X_p - X_c) . (a1, a2, a3)`` relative to the node ``X_c``; ``axes`` are the node-wise
    ``a1 = e1 / s``, ``a2 = e2 / s`` (``s`` a window scale, for conditioning) and ``a3 = n``, each
    (rows, cols, 3) and zero at non-candidates. The frames are known only now, so the sums that need them
    (moments of order 3 and 4, right-hand sides of the quadratic terms) loop over the k^2 window offsets,
    vectorised over all nodes. The lower-order ones are exact projections of the plane's window sums and come
    in as ``low_moment`` ({(p, q): (n_cand,)} for p + q <= 2) and ``low_rhs`` ((n_cand, 3, 4) for the basis
    functions 1, xi, eta).

    Returns ``(slope_xi, slope_eta, well_posed)`` at the candidates: (n_cand, 4) derivatives at the node of
    ``(u_x, u_y, u_z, h)`` (mm/mm) and the (n_cand,) mask of well-conditioned fits.
    """
    rows, cols = valid.shape
    pad = ((r, r), (r, r))
    a = [np.ascontiguousarray(np.moveaxis(v, -1, 0)) for v in axes]  # (3, rows, cols) each
    X_c = [np.ascontiguousarray(Xr[..., k]) for k in range(3)]
    a_dot_Xc = [ak[0] * X_c[0] + ak[1] * X_c[1] + ak[2] * X_c[2] for ak in a]
    Xp = [np.pad(X_c[k], pad) for k in range(3)]
    Up = [np.pad(np.ascontiguousarray(U[..., k]), pad) for k in range(3)]
    wp = np.pad(valid.astype(float), pad)

    high = [(3, 0), (2, 1), (1, 2), (0, 3), (4, 0), (3, 1), (2, 2), (1, 3), (0, 4)]
    moment = {pq: np.zeros((rows, cols)) for pq in high}
    rhs = np.zeros((3, 4, rows, cols))  # basis xi^2, xi eta, eta^2 x values u_x, u_y, u_z, h
    coord = [np.empty((rows, cols)) for _ in range(3)]
    tmp = np.empty((rows, cols))
    for di in range(2 * r + 1):
        for dj in range(2 * r + 1):
            window = (slice(di, di + rows), slice(dj, dj + cols))
            w = wp[window]
            x0, x1, x2 = Xp[0][window], Xp[1][window], Xp[2][window]
            for out, ak, off in zip(coord, a, a_dot_Xc):
                # (X_p - X_c) . a_k, zeroed for unmeasured points (their stored X_p is 0, not X_c).
                np.multiply(ak[0], x0, out=out)
                out += np.multiply(ak[1], x1, out=tmp)
                out += np.multiply(ak[2], x2, out=tmp)
                out -= off
                out *= w
            xi, eta, h = coord
            xi2, xieta, eta2 = xi * xi, xi * eta, eta * eta
            moment[(3, 0)] += np.multiply(xi2, xi, out=tmp)
            moment[(2, 1)] += np.multiply(xi2, eta, out=tmp)
            moment[(1, 2)] += np.multiply(xi, eta2, out=tmp)
            moment[(0, 3)] += np.multiply(eta2, eta, out=tmp)
            moment[(4, 0)] += np.multiply(xi2, xi2, out=tmp)
            moment[(3, 1)] += np.multiply(xi2, xieta, out=tmp)
            moment[(2, 2)] += np.multiply(xieta, xieta, out=tmp)
            moment[(1, 3)] += np.multiply(xieta, eta2, out=tmp)
            moment[(0, 4)] += np.multiply(eta2, eta2, out=tmp)
            values = (Up[0][window], Up[1][window], Up[2][window], h)  # U is already zero where unmeasured
            for i, phi in enumerate((xi2, xieta, eta2)):
                for k, v in enumerate(values):
                    rhs[i, k] += np.multiply(phi, v, out=tmp)

    count = low_moment[(0, 0)]
    moments = dict(low_moment)
    moments.update({pq: m[cand] for pq, m in moment.items()})
    M = np.empty((count.size, 6, 6))
    for i, (pi, qi) in enumerate(_QUAD_EXPONENTS):
        for j, (pj, qj) in enumerate(_QUAD_EXPONENTS):
            M[:, i, j] = moments[(pi + pj, qi + qj)] / count
    b = np.concatenate([low_rhs, np.moveaxis(rhs[:, :, cand], -1, 0)], axis=1) / count[:, None, None]
    finite = np.all(np.isfinite(M), axis=(1, 2)) & np.all(np.isfinite(b), axis=(1, 2))
    M[~finite] = np.eye(6)  # placeholder so the batched eigen/solve never sees NaN
    eig = np.linalg.eigvalsh(M)
    well_posed = finite & (eig[:, 0] > CONDITION_TOL * eig[:, -1])
    coef = np.full((count.size, 6, 4), np.nan)
    if well_posed.any():
        coef[well_posed] = np.linalg.solve(M[well_posed], b[well_posed])
    s = np.linalg.norm(axes[0][cand], axis=-1)[:, None]  # |a1| = 1 / s
    return coef[:, 1, :] * s, coef[:, 2, :] * s, well_posed


def _window_strain(X_ref: np.ndarray, X_def: np.ndarray, valid: np.ndarray, window: int, fit: str,
                   direction: np.ndarray, min_valid_fraction: float) -> SurfaceStrain:
    """Strain-window method; see :func:`surface_strain`."""
    rows, cols = valid.shape
    r = window // 2
    n_unknowns = 3 if fit == "linear" else 6
    # The small epsilon keeps e.g. 0.6 * 25 = 15.000000000000002 from demanding 16 points.
    min_count = max(math.ceil(min_valid_fraction * window * window - 1e-9), n_unknowns)

    # Coordinates and displacements relative to their means over the grid (not the camera origin), so the
    # window sums of products below lose few digits to cancellation; zero where not measured.
    w = valid.astype(float)
    Xr = np.where(valid[..., None], X_ref - X_ref[valid].mean(axis=0), 0.0)
    u = X_def - X_ref
    U = np.where(valid[..., None], u - u[valid].mean(axis=0), 0.0)

    ones = np.ones(window)
    lin = np.arange(-r, r + 1, dtype=float)
    XX = np.stack([Xr[..., a] * Xr[..., b] for a, b in _SYM], axis=-1)
    XU = (Xr[..., :, None] * U[..., None, :]).reshape(rows, cols, 9)
    S = _window_sums(np.concatenate([w[..., None], Xr, XX, U, XU], axis=-1), ones, ones)
    count, SX, SXX, SU, SXU = S[..., 0], S[..., 1:4], S[..., 4:10], S[..., 10:13], S[..., 13:22]
    # Sums weighted by the grid offsets (dj along columns, di along rows): for the index-space collinearity
    # test and for the grid-oriented sign of the normal.
    wX = np.concatenate([w[..., None], Xr], axis=-1)
    Sj, Si = _window_sums(wX, ones, lin), _window_sums(wX, lin, ones)
    Sjj = _window_sums(w, ones, lin ** 2)
    Sii = _window_sums(w, lin ** 2, ones)
    Sij = _window_sums(w, lin, lin)

    cand = valid & (count >= min_count - 0.5)
    with np.errstate(invalid="ignore", divide="ignore"):
        # All valid points on one grid line (row, column or diagonal) -> no 2-D fit. Tested on the integer grid
        # offsets, so it holds however curved the surface: an arc of points spans a plane in space (its
        # sagitta) that is not the surface's.
        var_j = Sjj - Sj[..., 0] ** 2 / count
        var_i = Sii - Si[..., 0] ** 2 / count
        cov_ij = Sij - Si[..., 0] * Sj[..., 0] / count
        cand &= var_i * var_j - cov_ij ** 2 > 1e-9 * var_i * var_j
    c = cand
    n_c = count[c]
    xbar = SX[c] / n_c[:, None]
    scatter = _symmetric(SXX[c]) - n_c[:, None, None] * xbar[:, :, None] * xbar[:, None, :]
    cross_scatter = SXU[c].reshape(-1, 3, 3) - xbar[:, :, None] * SU[c][:, None, :]  # sum (X - xbar)(u - ubar)^T
    a_col = Sj[c][:, 1:] - Sj[c][:, :1] * xbar
    a_row = Si[c][:, 1:] - Si[c][:, :1] * xbar

    # Plane of the window: total least squares (the eigenvector of the smallest scatter eigenvalue is the
    # SVD's normal), sign from the grid (dX/dj x dX/di regressed over the window).
    lam, vec = np.linalg.eigh(scatter)
    normal = vec[:, :, 0]
    grid_normal = _cross(a_col, a_row)
    orient = _dot(normal, grid_normal)
    normal = normal * np.sign(orient)[:, None]
    ok = (lam[:, 1] > COLLINEAR_TOL * lam[:, 2]) & (np.abs(orient) > 1e-12 * np.linalg.norm(grid_normal, axis=-1))
    e1, e2 = _tangent_frame(normal, direction)

    if fit == "linear":
        # In-plane scatter A = Q^T S Q and B = Q^T S_Xu (Q = [e1 e2]); LS gradient G = A^-1 B (rows d u/d xi,
        # d u/d eta). The slope of the normal offset h is zero by construction of the TLS plane, so the
        # reference tangents are e1, e2 themselves.
        Se1 = np.einsum("nab,nb->na", scatter, e1)
        Se2 = np.einsum("nab,nb->na", scatter, e2)
        A11, A12, A22 = _dot(e1, Se1), _dot(e1, Se2), _dot(e2, Se2)
        B1 = np.einsum("na,nab->nb", e1, cross_scatter)
        B2 = np.einsum("na,nab->nb", e2, cross_scatter)
        det = A11 * A22 - A12 ** 2
        with np.errstate(invalid="ignore", divide="ignore"):
            G1 = (A22[:, None] * B1 - A12[:, None] * B2) / det[:, None]
            G2 = (A11[:, None] * B2 - A12[:, None] * B1) / det[:, None]
        T1, T2 = e1, e2
    else:
        scale = np.sqrt((lam[:, 1] + lam[:, 2]) / n_c)[:, None]  # RMS in-plane distance from the centroid
        a1, a2, a3 = e1 / scale, e2 / scale, normal
        # Low-order sums about the node X_c, from the window sums: d = X_p - X_c has mean dbar.
        dbar = xbar - Xr[c]
        S_c = scatter + n_c[:, None, None] * dbar[:, :, None] * dbar[:, None, :]
        S_dU = cross_scatter + dbar[:, :, None] * SU[c][:, None, :]

        def quad(p, q):
            return np.einsum("na,nab,nb->n", p, S_c, q)

        low_moment = {(0, 0): n_c, (1, 0): n_c * _dot(a1, dbar), (0, 1): n_c * _dot(a2, dbar),
                      (2, 0): quad(a1, a1), (1, 1): quad(a1, a2), (0, 2): quad(a2, a2)}
        low_rhs = np.stack([
            np.concatenate([SU[c], (n_c * _dot(a3, dbar))[:, None]], axis=-1),
            np.concatenate([np.einsum("na,nab->nb", a1, S_dU), quad(a1, a3)[:, None]], axis=-1),
            np.concatenate([np.einsum("na,nab->nb", a2, S_dU), quad(a2, a3)[:, None]], axis=-1)], axis=1)
        full = []
        for src_axis in (a1, a2, a3):
            dst = np.zeros((rows, cols, 3))
            dst[c] = np.nan_to_num(src_axis)
            full.append(dst)
        slope_xi, slope_eta, well_posed = _quadratic_fit(Xr, U, valid, cand, r, tuple(full), low_moment, low_rhs)
        ok &= well_posed
        G1, G2 = slope_xi[:, :3], slope_eta[:, :3]
        # Reference tangents of the fitted surface X_c + xi e1 + eta e2 + h(xi, eta) n at the node: with an
        # asymmetric window (edges, holes) the TLS plane is tilted against the tangent plane; the fitted slope
        # of h corrects that. The frame is then rebuilt on the corrected tangent plane.
        T1 = e1 + slope_xi[:, 3:4] * normal
        T2 = e2 + slope_eta[:, 3:4] * normal
        normal = _unit(_cross(T1, T2))
        e1, e2 = _tangent_frame(normal, direction)

    with np.errstate(invalid="ignore", divide="ignore"):
        # Surface metric: reference tangents T_a, deformed t_a = T_a + du/dxi_a. With A_ab = e_a . T_b the
        # right Cauchy-Green tensor in (e1, e2) is C = A^-T (t^T t) A^-1, and E = (C - I) / 2. For T_a = e_a
        # this is E_ab = (du_a . e_b + du_b . e_a + du_a . du_b) / 2.
        t1, t2 = T1 + G1, T2 + G2
        A = np.stack([np.stack([_dot(e1, T1), _dot(e1, T2)], -1), np.stack([_dot(e2, T1), _dot(e2, T2)], -1)], -2)
        g = np.stack([np.stack([_dot(t1, t1), _dot(t1, t2)], -1), np.stack([_dot(t1, t2), _dot(t2, t2)], -1)], -2)
        detA = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
        Ainv = np.stack([np.stack([A[:, 1, 1], -A[:, 0, 1]], -1), np.stack([-A[:, 1, 0], A[:, 0, 0]], -1)], -2)
        Ainv = Ainv / detA[:, None, None]
        C = np.swapaxes(Ainv, -1, -2) @ g @ Ainv
        E11c, E22c, E12c = 0.5 * (C[:, 0, 0] - 1.0), 0.5 * (C[:, 1, 1] - 1.0), 0.5 * C[:, 0, 1]
        Jc = np.sqrt(C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] ** 2)
    ok &= np.isfinite(E11c) & np.isfinite(E22c) & np.isfinite(E12c) & np.all(np.isfinite(e1), axis=-1)

    def grid(values):
        out = np.full((rows, cols) + values.shape[1:], np.nan)
        out[c] = np.where(ok.reshape((-1,) + (1,) * (values.ndim - 1)), values, np.nan)
        return out

    E11, E22, E12 = grid(E11c), grid(E22c), grid(E12c)
    E1, E2, angle_deg, magnitude = _principal(E11, E22, E12)
    return SurfaceStrain(E11=E11, E22=E22, E12=E12, E1=E1, E2=E2, angle_deg=angle_deg, magnitude=magnitude,
                         area_change=grid(Jc - 1.0), e1=grid(e1), e2=grid(e2), n=grid(normal),
                         method="window", window=window, fit=fit, triangles=None)


# ---------------------------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------------------------

def surface_strain(X_ref_mm, X_def_mm, *, window: int | None = None, fit: str = "linear", direction_mm=None,
                   min_valid_fraction: float = 0.6) -> SurfaceStrain:
    """Surface Green-Lagrange strain at the grid nodes from reference and deformed point grids.

    ``window=None``: triangle method (Cosserat point elements, :func:`triangle_strain`); each node gets the
    area-weighted (reference areas) average of the strain components of its valid adjacent triangles (up to
    six; MultiDIC likewise averages face values to vertices), its normal is the area-weighted mean of their
    normals, and its ``area_change`` is ``sum A_def / sum A_ref - 1`` over them. Exact for a deformation that
    is homogeneous over the node's triangles.

    ``window=k`` (odd, >= 3): strain window. At each measured node, over the valid points of its k x k grid
    neighbourhood (at least ``ceil(min_valid_fraction * k^2)``, and not all on one grid line):

    1. the plane of the window: total least squares through the reference points (SVD normal of the centred
       points), oriented with the grid; ``e1`` = the reference direction projected into it, ``e2 = n x e1``;
    2. the displacement ``u = X_def - X_ref`` (all three components) is fitted by least squares in the
       in-plane coordinates ``(xi, eta)`` of the reference points about the node: ``fit="linear"``
       (``1, xi, eta``) or ``fit="quadratic"`` (adds ``xi^2, xi eta, eta^2``), giving ``du/dxi, du/deta`` at
       the node;
    3. ``E_ab = 1/2 (du_a . e_b + du_b . e_a + du_a . du_b)`` with ``du_1 = du/dxi``, ``du_2 = du/deta``,
       and ``area_change = sqrt(det(I + 2E)) - 1``.

    For ``fit="quadratic"`` the height ``h`` of the reference points above the plane is fitted with the same
    basis, and its slope at the node tilts the tangents to ``e_a + dh/dxi_a n`` (the plane of a one-sided
    window at an edge or hole is not the tangent plane); E and the frame are then those of that tangent
    plane. For the linear fit that slope is zero by construction of the TLS plane, so step 3 is exact as
    written. Any homogeneous deformation of a flat surface is reproduced exactly by both fits, and any rigid
    motion gives zero strain on any surface.

    Parameters
    ----------
    X_ref_mm, X_def_mm : array, shape (rows, cols, 3), mm
        Reference and deformed positions of the grid points (rows, cols >= 2); a point with a non-finite
        coordinate in either state is not measured and not used.
    window : int or None
        None for the triangle method, else the strain window in grid points per side (odd, >= 3).
    fit : {"linear", "quadratic"}
        Order of the window fit; only "linear" (the default) is accepted with ``window=None``.
    direction_mm : array, shape (3,), optional
        Reference direction for e1 (any length); default the mean grid direction along increasing column
        index, taken from ``X_ref_mm``.
    min_valid_fraction : float in (0, 1]
        Window method: least fraction of the k^2 window points that must be valid (at least 3 points for the
        linear, 6 for the quadratic fit); else the node is NaN.

    Returns
    -------
    SurfaceStrain

    Raises
    ------
    ValueError
        Bad or mismatched grid shapes, a window that is not an odd integer >= 3, an unknown ``fit``,
        a bad ``direction_mm`` or ``min_valid_fraction``.
    """
    X_ref, X_def, valid = _check_grids(X_ref_mm, X_def_mm)
    if fit not in _FITS:
        raise ValueError(f"fit must be one of {_FITS}, got {fit!r}")
    if window is not None:
        if (isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 3
                or window % 2 == 0):
            raise ValueError(f"window must be None or an odd integer >= 3, got {window!r}")
    elif fit != "linear":
        raise ValueError(f"fit={fit!r} applies to the window method only; pass window=k")
    if isinstance(min_valid_fraction, bool) or not (np.isscalar(min_valid_fraction)
                                                    and 0.0 < min_valid_fraction <= 1.0):
        raise ValueError(f"min_valid_fraction must be a number in (0, 1], got {min_valid_fraction!r}")
    direction = _reference_direction(direction_mm, X_ref, valid)
    rows, cols = valid.shape
    if window is None:
        tri = _triangle_strain(X_ref.reshape(-1, 3), X_def.reshape(-1, 3), valid.ravel(),
                               triangulate_grid(rows, cols), direction)
        return _nodal_from_triangles(tri, (rows, cols), direction)
    return _window_strain(X_ref, X_def, valid, int(window), fit, direction, float(min_valid_fraction))
