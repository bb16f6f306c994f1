"""First- and second-order subset shape functions and their inverse composition (numba).

A subset point at offset ``(dx, dy)`` from the point of interest maps to

    dx' = dx + u + ux dx + uy dy + 1/2 uxx dx^2 + uxy dx dy + 1/2 uyy dy^2
    dy' = dy + v + vx dx + vy dy + 1/2 vxx dx^2 + vxy dx dy + 1/2 vyy dy^2

The parameter vector always has 12 entries, in this order (:data:`PARAMETER_NAMES`); a first-order shape
function keeps the six second-order entries at zero. The inverse-compositional update of IC-GN,
``W(p) <- W(p) o W(dp)^-1``, is done on the matrix form of the warp: 3 x 3 homogeneous for the first order, and
the 6 x 6 form of Gao et al. (2015), "High-efficiency and high-accuracy digital image correlation for
three-dimensional measurement", Opt. Lasers Eng. 65, 73-80, for the second order (it acts on
``(dx^2, dx dy, dy^2, dx, dy, 1)`` and drops the third- and fourth-order terms).
"""
from __future__ import annotations

import numba
import numpy as np

PARAMETER_NAMES = ("u", "ux", "uy", "uxx", "uxy", "uyy", "v", "vx", "vy", "vxx", "vxy", "vyy")
N_PARAMETERS = 12
#: Indices of the second-order terms.
SECOND_ORDER = [3, 4, 5, 9, 10, 11]


@numba.njit(cache=True)
def warp_matrix_2(p):
    """6 x 6 matrix of the second-order warp ``p`` (12,) acting on (dx^2, dx dy, dy^2, dx, dy, 1)."""
    u, ux, uy, uxx, uxy, uyy, v, vx, vy, vxx, vxy, vyy = p[0], p[1], p[2], p[3], p[4], p[5], \
        p[6], p[7], p[8], p[9], p[10], p[11]
    a1, a2, a3 = 0.5 * uxx, uxy, 0.5 * uyy
    b1, b2, b3 = 0.5 * vxx, vxy, 0.5 * vyy
    sx = 1.0 + ux
    sy = 1.0 + vy
    w = np.zeros((6, 6))
    w[0, 0] = sx * sx + 2.0 * u * a1
    w[0, 1] = 2.0 * sx * uy + 2.0 * u * a2
    w[0, 2] = uy * uy + 2.0 * u * a3
    w[0, 3] = 2.0 * u * sx
    w[0, 4] = 2.0 * u * uy
    w[0, 5] = u * u
    w[1, 0] = sx * vx + u * b1 + v * a1
    w[1, 1] = sx * sy + uy * vx + u * b2 + v * a2
    w[1, 2] = uy * sy + u * b3 + v * a3
    w[1, 3] = u * vx + v * sx
    w[1, 4] = u * sy + v * uy
    w[1, 5] = u * v
    w[2, 0] = vx * vx + 2.0 * v * b1
    w[2, 1] = 2.0 * vx * sy + 2.0 * v * b2
    w[2, 2] = sy * sy + 2.0 * v * b3
    w[2, 3] = 2.0 * v * vx
    w[2, 4] = 2.0 * v * sy
    w[2, 5] = v * v
    w[3, 0] = a1
    w[3, 1] = a2
    w[3, 2] = a3
    w[3, 3] = sx
    w[3, 4] = uy
    w[3, 5] = u
    w[4, 0] = b1
    w[4, 1] = b2
    w[4, 2] = b3
    w[4, 3] = vx
    w[4, 4] = sy
    w[4, 5] = v
    w[5, 5] = 1.0
    return w


@numba.njit(cache=True)
def compose_inverse(p, dp, order):
    """Inverse-compositional update ``W(p) o W(dp)^-1``, in place on ``p`` (12,).

    Returns False (``p`` untouched) when ``W(dp)`` is singular.
    """
    if order == 1:
        # Homogeneous 3 x 3 affine matrices.
        a = 1.0 + dp[1]
        b = dp[2]
        c = dp[7]
        d = 1.0 + dp[8]
        det = a * d - b * c
        if abs(det) < 1e-12:
            return False
        ia, ib, ic, id_ = d / det, -b / det, -c / det, a / det
        itx = -(ia * dp[0] + ib * dp[6])
        ity = -(ic * dp[0] + id_ * dp[6])
        m11, m12, m13 = 1.0 + p[1], p[2], p[0]
        m21, m22, m23 = p[7], 1.0 + p[8], p[6]
        p[1] = m11 * ia + m12 * ic - 1.0
        p[2] = m11 * ib + m12 * id_
        p[0] = m11 * itx + m12 * ity + m13
        p[7] = m21 * ia + m22 * ic
        p[8] = m21 * ib + m22 * id_ - 1.0
        p[6] = m21 * itx + m22 * ity + m23
        return True
    w_delta = warp_matrix_2(dp)
    if abs(np.linalg.det(w_delta)) < 1e-12:
        return False
    w = warp_matrix_2(p) @ np.linalg.inv(w_delta)
    p[3] = 2.0 * w[3, 0]
    p[4] = w[3, 1]
    p[5] = 2.0 * w[3, 2]
    p[1] = w[3, 3] - 1.0
    p[2] = w[3, 4]
    p[0] = w[3, 5]
    p[9] = 2.0 * w[4, 0]
    p[10] = w[4, 1]
    p[11] = 2.0 * w[4, 2]
    p[7] = w[4, 3]
    p[8] = w[4, 4] - 1.0
    p[6] = w[4, 5]
    return True


@numba.njit(cache=True)
def shift_parameters(p, dx, dy, out):
    """Parameters of the same deformation seen from a point offset by ``(dx, dy)`` px (Taylor transfer).

    Used to start a neighbour from a converged point: its displacement is the warp evaluated at the offset,
    its gradients are the first-order terms plus the second-order ones times the offset.
    """
    out[0] = p[0] + p[1] * dx + p[2] * dy + 0.5 * p[3] * dx * dx + p[4] * dx * dy + 0.5 * p[5] * dy * dy
    out[1] = p[1] + p[3] * dx + p[4] * dy
    out[2] = p[2] + p[4] * dx + p[5] * dy
    out[6] = p[6] + p[7] * dx + p[8] * dy + 0.5 * p[9] * dx * dx + p[10] * dx * dy + 0.5 * p[11] * dy * dy
    out[7] = p[7] + p[9] * dx + p[10] * dy
    out[8] = p[8] + p[10] * dx + p[11] * dy
    for k in (3, 4, 5, 9, 10, 11):
        out[k] = p[k]


def warp_points(p: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Displacement ``(u, v)`` (px) that shape-function parameters ``p`` (12,) give at offsets ``dx, dy``."""
    p = np.asarray(p, dtype=np.float64)
    u = p[0] + p[1] * dx + p[2] * dy + 0.5 * p[3] * dx * dx + p[4] * dx * dy + 0.5 * p[5] * dy * dy
    v = p[6] + p[7] * dx + p[8] * dy + 0.5 * p[9] * dx * dx + p[10] * dx * dy + 0.5 * p[11] * dy * dy
    return u, v
