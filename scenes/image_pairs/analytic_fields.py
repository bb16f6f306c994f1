"""Analytic 2-D displacement fields for exact image pairs (the truth side, no rendering): :class:`Translation`,
:class:`HomogeneousStrain`, :class:`Rotation`, :class:`QuadraticField`, and :func:`solve_reference_positions`,
which inverts ``x = X + u(X)`` for the material point a deformed pixel shows.

The image pairs built on them: :mod:`scenes.image_pairs.gaussian_speckle` (any smooth field) and
:mod:`scenes.image_pairs.fourier_shift` (translations).

Conventions (both sources)
--------------------------
* ``x`` is the column coordinate, ``y`` the row coordinate, in pixels; pixel (row i, column j) has its centre
  at ``(x, y) = (j, i)``. Points are given as ``(x, y)`` pairs, images as ``(rows, cols)`` arrays.
* A displacement ``u = (U, V)`` maps the reference (material) point ``X`` to ``x = X + u(X)``; the deformed
  image is ``g(x) = f(X)``: the content moves by ``+u``.
* **Image formation is point sampling**: pixel values are the pattern's values at the pixel centres, with no
  pixel integration and no optical blur. The DIC truth is therefore exactly ``u`` at the material point: a
  subset centred on reference pixel ``X`` has moved by ``u(X)``; the deformed pixel ``x`` shows the material
  point ``X`` solved from ``X + u(X) = x`` (:func:`solve_reference_positions`).
* Grey levels are float64 in an 8-bit-like range, neither noisy nor quantised; use
  :func:`scenes.sensor.noise.apply_sensor_noise` for shot/read noise and quantisation.

"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scenes.surfaces.speckle import require_finite, require_positive_finite

#: Default convergence tolerance of :func:`solve_reference_positions`, in px.
DEFAULT_TOLERANCE_PX = 1e-10

#: Signature of a displacement field: ``(X, Y) -> (U, V)``, arrays in px, all of the same shape.
DisplacementField = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def solve_reference_positions(x: np.ndarray, y: np.ndarray, displacement: DisplacementField, *,
                              tol_px: float = DEFAULT_TOLERANCE_PX,
                              max_iter: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Material points ``X`` that a displacement field carries to the given points: ``X + u(X) = x``.

    With a ``gradient`` method on ``displacement`` (all fields of this module) Newton's method is used,
    ``X <- X - (I + grad u)^-1 (X + u(X) - x)``, from ``X = x - u(x)``: exact in one step for affine fields
    (translation, strain, rotation by any angle), and a few steps for smooth nonlinear ones. Otherwise the
    fixed-point iteration ``X <- x - u(X)`` is used; it converges linearly with rate ``max ||grad u||``, e.g.
    ~35 iterations for ``|grad u| = 0.5``, and diverges for ``|grad u| >= 1``. Iteration stops when
    ``max |X + u(X) - x| <= tol_px`` over all points.

    Parameters
    ----------
    x, y : ndarray
        Deformed-configuration points in px, same shape, finite.
    displacement : callable
        ``(X, Y) -> (U, V)`` in px, returning arrays of the shape of ``X``.
    tol_px : float
        Residual tolerance in px (> 0).
    max_iter : int
        Iteration limit (>= 1).

    Returns
    -------
    X, Y : ndarray of float64, shape of ``x``

    Raises
    ------
    ValueError
        If the residual is still above ``tol_px`` after ``max_iter`` iterations, or becomes non-finite, or
        ``I + grad u`` is singular (the mapping folds over).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same shape, got {x.shape} and {y.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x and y must be finite")
    if not callable(displacement):
        raise TypeError(f"displacement must be a callable (X, Y) -> (U, V), got {displacement!r}")
    tol = require_positive_finite(tol_px, "tol_px")
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    gradient = getattr(displacement, "gradient", None)
    newton = callable(gradient)

    U, V = _call_field(displacement, x, y)
    X, Y = x - U, y - V
    residual = np.inf
    for iteration in range(int(max_iter) + 1):
        U, V = _call_field(displacement, X, Y)
        rx, ry = X + U - x, Y + V - y
        residual = float(max(np.max(np.abs(rx), initial=0.0), np.max(np.abs(ry), initial=0.0)))
        if residual <= tol:
            return X, Y
        if not np.isfinite(residual) or iteration == max_iter:
            break
        if newton:
            dudx, dudy, dvdx, dvdy = _call_gradient(gradient, X, Y)
            j11, j12, j21, j22 = 1.0 + dudx, dudy, dvdx, 1.0 + dvdy
            det = j11 * j22 - j12 * j21
            if not np.all(np.abs(det) > 1e-12):
                raise ValueError("displacement folds the plane over (det(I + grad u) = 0 at some points): "
                                 "the deformed image is not defined")
            X = X - (j22 * rx - j12 * ry) / det
            Y = Y - (-j21 * rx + j11 * ry) / det
        else:
            X, Y = X - rx, Y - ry
    if newton:
        method, hint = "Newton", "X -> X + u(X) must be smooth and one-to-one, det(I + grad u) > 0"
    else:
        method, hint = "fixed-point", ("fixed-point iteration needs |grad u| < 1, ideally < 0.5; give the "
                                       "field a gradient method to use Newton's method")
    raise ValueError(
        f"inverting the displacement field did not converge ({method}, {max_iter} iterations): residual "
        f"{residual:.3g} px > tol_px={tol}; {hint}")



# ------------------------------------------------------------------------------------------------------------
# Displacement fields: (X, Y) -> (U, V) and gradient (X, Y) -> (dU/dX, dU/dY, dV/dX, dV/dY), all in px.
# ------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Translation:
    """Rigid translation ``u = (ux_px, uy_px)`` everywhere."""

    ux_px: float
    uy_px: float

    def __post_init__(self):
        object.__setattr__(self, "ux_px", require_finite(self.ux_px, "ux_px"))
        object.__setattr__(self, "uy_px", require_finite(self.uy_px, "uy_px"))

    def __call__(self, X, Y):
        X, Y = broadcast_xy(X, Y)
        return np.full_like(X, self.ux_px), np.full_like(Y, self.uy_px)

    def gradient(self, X, Y):
        """``(dU/dX, dU/dY, dV/dX, dV/dY)``: all zero, shape of ``X``."""
        X, _ = broadcast_xy(X, Y)
        zero = np.zeros_like(X)
        return zero, zero.copy(), zero.copy(), zero.copy()


@dataclass(frozen=True)
class HomogeneousStrain:
    """Homogeneous small-strain field about a centre, no rotation.

    ``U = exx (X - xc) + exy (Y - yc)``, ``V = exy (X - xc) + eyy (Y - yc)``: the displacement gradient is the
    symmetric strain tensor ``[[exx, exy], [exy, eyy]]``; ``exy`` is the tensorial shear strain (engineering
    shear ``gamma_xy = 2 exy``). The centre does not move.
    """

    exx: float
    eyy: float
    exy: float = 0.0
    centre_xy_px: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        for name in ("exx", "eyy", "exy"):
            object.__setattr__(self, name, require_finite(getattr(self, name), name))
        object.__setattr__(self, "centre_xy_px", check_xy(self.centre_xy_px, "centre_xy_px"))

    def __call__(self, X, Y):
        X, Y = broadcast_xy(X, Y)
        dx, dy = X - self.centre_xy_px[0], Y - self.centre_xy_px[1]
        return self.exx * dx + self.exy * dy, self.exy * dx + self.eyy * dy

    def gradient(self, X, Y):
        """``(dU/dX, dU/dY, dV/dX, dV/dY) = (exx, exy, exy, eyy)``, each of the shape of ``X``."""
        X, _ = broadcast_xy(X, Y)
        return tuple(np.full_like(X, value) for value in (self.exx, self.exy, self.exy, self.eyy))


@dataclass(frozen=True)
class Rotation:
    """Finite (exact) rigid rotation by ``angle_deg`` about a centre.

    ``x = c + Rot (X - c)`` with ``Rot = [[cos a, -sin a], [sin a, cos a]]``, so ``u = (Rot - I)(X - c)``.
    A positive angle turns +x towards +y, which is clockwise on screen (rows go down).
    """

    angle_deg: float
    centre_xy_px: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, "angle_deg", require_finite(self.angle_deg, "angle_deg"))
        object.__setattr__(self, "centre_xy_px", check_xy(self.centre_xy_px, "centre_xy_px"))

    def _matrix_minus_identity(self):
        a = np.deg2rad(self.angle_deg)
        # cos a - 1 = -2 sin^2(a/2): no cancellation for small angles.
        return -2.0 * np.sin(0.5 * a) ** 2, np.sin(a)

    def __call__(self, X, Y):
        X, Y = broadcast_xy(X, Y)
        cm1, s = self._matrix_minus_identity()
        dx, dy = X - self.centre_xy_px[0], Y - self.centre_xy_px[1]
        return cm1 * dx - s * dy, s * dx + cm1 * dy

    def gradient(self, X, Y):
        """``(dU/dX, dU/dY, dV/dX, dV/dY) = (cos a - 1, -sin a, sin a, cos a - 1)``, shape of ``X``."""
        X, _ = broadcast_xy(X, Y)
        cm1, s = self._matrix_minus_identity()
        return tuple(np.full_like(X, value) for value in (cm1, -s, s, cm1))


@dataclass(frozen=True)
class QuadraticField:
    """Pure second-order displacement field about a centre.

    With ``dx = X - xc``, ``dy = Y - yc``, ``u_coeffs = (a_xx, a_xy, a_yy)``, ``v_coeffs = (b_xx, b_xy, b_yy)``:
    ``U = a_xx dx^2 + a_xy dx dy + a_yy dy^2`` and ``V = b_xx dx^2 + b_xy dx dy + b_yy dy^2`` (coefficients in
    1/px). The centre does not move and the gradient vanishes there; it grows linearly away from it, e.g.
    ``dU/dX = 2 a_xx dx + a_xy dy``. Keep ``|grad u|`` well below 1 over the image (``|a| * size << 1/2``).
    """

    u_coeffs: tuple[float, float, float]
    v_coeffs: tuple[float, float, float]
    centre_xy_px: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        for name in ("u_coeffs", "v_coeffs"):
            object.__setattr__(self, name, check_n_floats(getattr(self, name), 3, name))
        object.__setattr__(self, "centre_xy_px", check_xy(self.centre_xy_px, "centre_xy_px"))

    def __call__(self, X, Y):
        X, Y = broadcast_xy(X, Y)
        dx, dy = X - self.centre_xy_px[0], Y - self.centre_xy_px[1]
        (a_xx, a_xy, a_yy), (b_xx, b_xy, b_yy) = self.u_coeffs, self.v_coeffs
        return (a_xx * dx * dx + a_xy * dx * dy + a_yy * dy * dy,
                b_xx * dx * dx + b_xy * dx * dy + b_yy * dy * dy)

    def gradient(self, X, Y):
        """``(dU/dX, dU/dY, dV/dX, dV/dY)``, each of the shape of ``X``."""
        X, Y = broadcast_xy(X, Y)
        dx, dy = X - self.centre_xy_px[0], Y - self.centre_xy_px[1]
        (a_xx, a_xy, a_yy), (b_xx, b_xy, b_yy) = self.u_coeffs, self.v_coeffs
        return (2.0 * a_xx * dx + a_xy * dy, a_xy * dx + 2.0 * a_yy * dy,
                2.0 * b_xx * dx + b_xy * dy, b_xy * dx + 2.0 * b_yy * dy)


def _call_field(displacement, X, Y) -> tuple[np.ndarray, np.ndarray]:
    result = displacement(X, Y)
    try:
        U, V = result
    except (TypeError, ValueError):
        raise ValueError(f"displacement(X, Y) must return a pair (U, V) of arrays, got {type(result)}") from None
    U = np.asarray(U, dtype=np.float64)
    V = np.asarray(V, dtype=np.float64)
    if U.shape != X.shape or V.shape != X.shape:
        raise ValueError(f"displacement(X, Y) must return U, V of shape {X.shape}, got {U.shape} and {V.shape}")
    return U, V


def _call_gradient(gradient, X, Y) -> tuple[np.ndarray, ...]:
    parts = tuple(np.asarray(g, dtype=np.float64) for g in gradient(X, Y))
    if len(parts) != 4 or any(p.shape != X.shape for p in parts):
        raise ValueError(f"displacement.gradient(X, Y) must return 4 arrays of shape {X.shape} "
                         "(dU/dX, dU/dY, dV/dX, dV/dY)")
    return parts


def broadcast_xy(X, Y) -> tuple[np.ndarray, np.ndarray]:
    X, Y = np.broadcast_arrays(np.asarray(X, dtype=np.float64), np.asarray(Y, dtype=np.float64))
    return X, Y


def check_xy(value, name: str) -> tuple[float, float]:
    return check_n_floats(value, 2, name)


def check_n_floats(value, n: int, name: str) -> tuple[float, ...]:
    try:
        values = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} numbers, got {value!r}") from None
    if values.shape != (n,):
        raise ValueError(f"{name} must be {n} numbers, got {value!r}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return tuple(float(v) for v in values)
