"""Levenberg-Marquardt for bundle-adjustment-structured least squares, pose blocks eliminated by Schur complement.

Problem: minimise ``cost(x) = 0.5 ||r(x)||^2`` over ``x = [shared (k), pose of view 0 (b), pose of view 1 (b),
...]`` where the residual rows ``view_rows[v]`` depend only on the shared parameters (intrinsics, stereo pose)
and view v's own ``b`` pose parameters. The Jacobian is then block-sparse::

    J = [ S_0  P_0            ]        S_v = d r[view_rows[v]] / d shared      (R, k)
        [ S_1       P_1       ]        P_v = d r[view_rows[v]] / d pose_v      (R, b)
        [ ...            ...  ]

and the normal matrix ``J^T J = [[U, W], [W^T, blockdiag(V_v)]]`` has ``U = sum S_v^T S_v`` (k, k),
``W_v = S_v^T P_v`` (k, b), ``V_v = P_v^T P_v`` (b, b). Each damped LM step eliminates the pose blocks (b x b
inverses, one per view), solves the reduced ``k x k`` system for the shared parameters and back-substitutes:
O(V (k^2 + b^3) R) work per iteration instead of the O(m n^2) dense QR of MINPACK (n = k + b V).

The damping is Marquardt's, on the scaled variables ``D x`` with ``D_j`` MINPACK's column scaling (the largest
Jacobian column norm seen so far), so focal lengths in px and distortion coefficients of order 1 are damped
alike; the damping factor follows Nielsen's rule (H. B. Nielsen, *Damping parameter in Marquardt's method*,
IMM-REP-1999-05). The stopping tests are MINPACK's: relative cost reduction (actual and predicted) ``ftol``,
scaled step ``||D dx|| <= xtol ||D x||``, and the largest cosine between the residual vector and a Jacobian
column ``gtol``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve


@dataclass(frozen=True)
class BlockJacobian:
    """Residuals and Jacobian of a block-structured problem, gathered per view.

    Attributes
    ----------
    residual : (m,) residual vector ``r(x)`` in its own row order
    shared : (V, R, k) ``d r[view_rows[v]] / d shared``
    pose : (V, R, b) ``d r[view_rows[v]] / d pose_v``
    view_rows : (V, R) int, the rows of ``residual`` that belong to each view (a partition of range(m))
    """

    residual: np.ndarray
    shared: np.ndarray
    pose: np.ndarray
    view_rows: np.ndarray

    def normal_equations(self):
        """Blocks of ``J^T J`` and ``g = J^T r``.

        Returns
        -------
        U : (k, k)
        W : (V, k, b)
        Vb : (V, b, b)
        g_shared : (k,)
        g_pose : (V, b)
        """
        r_v = self.residual[self.view_rows]                                 # (V, R)
        V, R, k = self.shared.shape
        S = self.shared.reshape(V * R, k)
        U = S.T @ S
        W = np.einsum("vrk,vrj->vkj", self.shared, self.pose)
        Vb = np.einsum("vri,vrj->vij", self.pose, self.pose)
        g_shared = S.T @ r_v.ravel()
        g_pose = np.einsum("vrj,vr->vj", self.pose, r_v)
        return U, W, Vb, g_shared, g_pose

    def dense(self) -> np.ndarray:
        """The whole Jacobian as a dense (m, k + V b) array, columns ordered as ``x`` (for MINPACK)."""
        V, R, k = self.shared.shape
        b = self.pose.shape[2]
        J = np.zeros((len(self.residual), k + V * b))
        J[self.view_rows.ravel(), :k] = self.shared.reshape(V * R, k)
        for v in range(V):
            J[self.view_rows[v], k + b * v:k + b * (v + 1)] = self.pose[v]
        return J

    def normal_matrix(self) -> np.ndarray:
        """The dense ``J^T J``, (k + V b, k + V b), parameters ordered as ``x`` (for the covariance)."""
        U, W, Vb, _, _ = self.normal_equations()
        V, k, b = W.shape
        n = k + V * b
        N = np.zeros((n, n))
        N[:k, :k] = U
        N[:k, k:] = W.transpose(1, 0, 2).reshape(k, V * b)
        N[k:, :k] = N[:k, k:].T
        for v in range(V):
            N[k + b * v:k + b * (v + 1), k + b * v:k + b * (v + 1)] = Vb[v]
        return N


def block_fd_jacobian(residual: Callable[[np.ndarray], np.ndarray], x: np.ndarray, n_shared: int,
                      view_rows: np.ndarray, block_size: int = 6) -> BlockJacobian:
    """Central-difference Jacobian exploiting the block structure.

    One evaluation pair per shared parameter, and one per pose component with that component of every view
    perturbed at once (views do not share residual rows): ``2 (n_shared + block_size)`` evaluations in all.
    Steps: ``1e-6 max(1, |x_j|)`` for shared parameters (px-sized focal lengths, order-1 distortion),
    ``1e-7 max(1, |x_j|)`` for poses (rad, mm).

    Parameters
    ----------
    residual : x (n,) -> r (m,)
    x : (n,) with ``n = n_shared + V block_size``
    view_rows : (V, R) int, rows of r that depend on each view's pose
    """
    x = np.asarray(x, float)
    rows = np.asarray(view_rows)
    V, R = rows.shape
    k, b = n_shared, block_size
    r0 = residual(x)
    J_shared = np.empty((V, R, k))
    J_pose = np.empty((V, R, b))
    for j in range(k):
        h = 1e-6 * max(1.0, abs(x[j]))
        e = np.zeros_like(x)
        e[j] = h
        J_shared[:, :, j] = ((residual(x + e) - residual(x - e)) / (2 * h))[rows]
    for c in range(b):
        idx = k + b * np.arange(V) + c
        h = 1e-7 * np.maximum(1.0, np.abs(x[idx]))
        e = np.zeros_like(x)
        e[idx] = h
        J_pose[:, :, c] = (residual(x + e) - residual(x - e))[rows] / (2 * h[:, None])
    return BlockJacobian(r0, J_shared, J_pose, rows)


@dataclass(frozen=True)
class LMResult:
    """Outcome of :func:`levenberg_marquardt`.

    Attributes
    ----------
    x : (n,) solution
    cost : ``0.5 ||r(x)||^2`` at ``x``
    n_iter : Jacobian evaluations (outer iterations)
    nfev : residual evaluations for trial steps (Jacobian evaluations not counted, as in MINPACK)
    status : converged: ``"ftol"``, ``"xtol"``, ``"gtol"`` or ``"zero residual"``; not converged:
        ``"max_iter"``, ``"non-finite gradient"`` or ``"stalled"`` (no acceptable step however damped)
    """

    x: np.ndarray
    cost: float
    n_iter: int
    nfev: int
    status: str

    @property
    def success(self) -> bool:
        return self.status in ("ftol", "xtol", "gtol", "zero residual")


def _damped_step(U, W, Vb, g_shared, g_pose, scale_shared, scale_pose, mu):
    """Solve ``(J^T J + mu D^2) dx = -g`` by eliminating the pose blocks; None if not positive definite.

    Works on the scaled variables ``D dx`` (unit diagonal at the current Jacobian), which keeps the reduced
    system well scaled although focal lengths (~1e4 px) and distortion coefficients (~1) share it.
    """
    k = len(U)
    b = Vb.shape[1]
    Us = U / np.outer(scale_shared, scale_shared) + mu * np.eye(k)
    Ws = W / (scale_shared[None, :, None] * scale_pose[:, None, :])               # (V, k, b)
    Vs = Vb / (scale_pose[:, :, None] * scale_pose[:, None, :]) + mu * np.eye(b)   # (V, b, b)
    gs = g_shared / scale_shared
    gp = g_pose / scale_pose
    try:
        Vs_inv = np.linalg.inv(Vs)                                                 # (V, b, b), one per view
    except np.linalg.LinAlgError:
        return None
    Vinv_Wt = Vs_inv @ Ws.transpose(0, 2, 1)                                       # (V, b, k)
    Vinv_g = np.einsum("vij,vj->vi", Vs_inv, gp)                                   # (V, b)
    S = Us - np.einsum("vkb,vbl->kl", Ws, Vinv_Wt)
    rhs = -gs + np.einsum("vkb,vb->k", Ws, Vinv_g)
    try:
        d_shared = cho_solve(cho_factor(S), rhs)
    except np.linalg.LinAlgError:
        return None
    d_pose = -Vinv_g - np.einsum("vbk,k->vb", Vinv_Wt, d_shared)
    return np.concatenate([d_shared / scale_shared, (d_pose / scale_pose).ravel()])


def levenberg_marquardt(residual: Callable[[np.ndarray], np.ndarray],
                        jacobian: Callable[[np.ndarray], BlockJacobian], x0: np.ndarray, *, ftol: float = 1e-12,
                        xtol: float = 1e-12, gtol: float = 1e-12, max_iter: int = 200,
                        mu0: float = 1e-12) -> LMResult:
    """Minimise ``0.5 ||r(x)||^2`` for a block-structured Jacobian (see the module docstring).

    Parameters
    ----------
    residual : x (n,) -> r (m,); a non-finite cost rejects the trial step
    jacobian : x (n,) -> :class:`BlockJacobian` at x (its ``residual`` is r(x))
    x0 : (n,) start
    ftol, xtol, gtol : MINPACK's stopping tolerances (module docstring)
    max_iter : most Jacobian evaluations
    mu0 : initial damping relative to the (unit) scaled diagonal of ``J^T J``. The default makes the first
        trial practically a Gauss-Newton step, as MINPACK's initial trust region (100 ||D x||) does: a
        rejected trial costs one residual evaluation, a Jacobian 2 (k + b), and starts are usually good.

    Returns
    -------
    LMResult (``x`` is the last accepted point, also when not converged)
    """
    x = np.array(x0, float)
    jac = jacobian(x)
    cost = 0.5 * float(jac.residual @ jac.residual)
    k = jac.shared.shape[2]
    V, _, b = jac.pose.shape
    col_norm = None
    mu, nu = mu0, 2.0
    nfev = 0
    for it in range(1, max_iter + 1):
        if cost == 0.0:
            return LMResult(x, cost, it, nfev, "zero residual")
        U, W, Vb, g_shared, g_pose = jac.normal_equations()
        diag = np.sqrt(np.concatenate([np.diag(U), np.einsum("vii->vi", Vb).ravel()]))
        # MINPACK's scaling: the largest column norm seen so far (a column that vanishes keeps a unit scale).
        col_norm = np.where(diag > 0, diag, 1.0) if col_norm is None else np.maximum(col_norm, diag)
        g = np.concatenate([g_shared, g_pose.ravel()])
        if not np.all(np.isfinite(g)):
            return LMResult(x, cost, it, nfev, "non-finite gradient")
        if np.max(np.abs(g) / (col_norm * np.sqrt(2.0 * cost))) <= gtol:
            return LMResult(x, cost, it, nfev, "gtol")
        x_norm = np.linalg.norm(col_norm * x)
        while True:
            dx = _damped_step(U, W, Vb, g_shared, g_pose, col_norm[:k], col_norm[k:].reshape(V, b), mu)
            if mu > 1e30:                      # damped to nothing without an acceptable step
                return LMResult(x, cost, it, nfev, "stalled")
            if dx is None:                     # numerically not positive definite: damp harder
                mu, nu = mu * nu, 2.0 * nu
                continue
            step_norm = np.linalg.norm(col_norm * dx)
            x_new = x + dx
            r_new = residual(x_new)
            nfev += 1
            cost_new = 0.5 * float(r_new @ r_new)
            # Predicted reduction of the linear model: 0.5 dx^T (mu D^2 dx - g).
            predicted = 0.5 * float(dx @ (mu * col_norm ** 2 * dx - g))
            rho = (cost - cost_new) / predicted if np.isfinite(cost_new) and predicted > 0 else -1.0
            if rho > 0:
                # MINPACK's ftol test: actual and predicted reductions relative to the cost before the step.
                converged_f = (cost - cost_new) <= ftol * cost and predicted <= ftol * cost and rho <= 2.0
                x, cost = x_new, cost_new
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                if converged_f:
                    return LMResult(x, cost, it, nfev, "ftol")
                if step_norm <= xtol * x_norm:
                    return LMResult(x, cost, it, nfev, "xtol")
                break
            mu, nu = mu * nu, 2.0 * nu
            if step_norm <= xtol * x_norm:     # the damped steps have shrunk to nothing: converged
                return LMResult(x, cost, it, nfev, "xtol")
        jac = jacobian(x)
    return LMResult(x, cost, max_iter, nfev, "max_iter")
