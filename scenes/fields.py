"""Displacement fields of a specimen (truth side): rigid motions, the beam in three-point bending, user FE results.

Every field is a :class:`DisplacementField`: ``u(X)`` in the specimen frame of
:class:`scenes.specimens.BendingSpecimen` (mm; origin at the centre of the speckled front face, x along the
length, y along the height pointing DOWN, so the top face is ``y = -H/2`` and the bottom face ``y = +H/2``,
z into the material, front face ``z = 0``, back face ``z = T``). A field is also a plain callable
(``field(X)`` is the displacement), which is what ``BendingSpecimen.surfaces(displacement_mm=...)`` takes.

* :class:`RigidMotionField`, :class:`ScaledField` (a load state = unit-load solution x load, linear
  elasticity), :class:`DifferenceField` (a state relative to a preloaded reference).
* :func:`solve_three_point_bending` / :func:`three_point_bending_field`: a 3-D linear-elastic finite-element
  solution (scikit-fem, triquadratic 27-node hexahedra) of the aluminium beam in three-point bending, with
  :func:`timoshenko_midspan_deflection_mm` and :func:`beam_theory_outer_fibre_strain` to compare it with, and
  :func:`three_point_bending_report` for the figures (Timoshenko comparison, mesh refinement).
* :class:`FEMeshField`: nodal displacements of a user's FE result read with meshio (VTU / legacy VTK,
  Exodus through meshio), interpolated with each element's own shape functions; :func:`check_covers_face`
  refuses a mesh that does not cover the specimen's front face.

The truth side never imports ``measurement/``. scikit-fem and meshio are imported only where used, so
importing this module stays cheap.
"""
from __future__ import annotations

import functools
import os
import re
import time
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "DisplacementField", "SupportsDisplacementField", "RigidMotionField", "ScaledField", "DifferenceField",
    "ThreePointBending", "ThreePointBendingSolution", "solve_three_point_bending", "three_point_bending_field",
    "timoshenko_shear_coefficient", "timoshenko_midspan_deflection_mm", "beam_theory_bending_moment_Nmm",
    "beam_theory_outer_fibre_strain", "fe_midspan_deflection_mm", "section_resultants",
    "three_point_bending_report", "FEMeshField", "check_covers_face",
]


# ------------------------------------------------------------------------------------------------------------
# Points and domain errors
def _as_points(X, name: str = "X_specimen_mm") -> np.ndarray:
    """Validated (N, 3) float64 copy-free view of ``X``."""
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"{name} must be (N, 3) in mm, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name} must be finite")
    return X


def _bbox_text(X: np.ndarray) -> str:
    lo, hi = X.min(axis=0), X.max(axis=0)
    return ", ".join(f"{c} in [{a:.6g}, {b:.6g}] mm" for c, a, b in zip("xyz", lo, hi))


def _raise_outside(X: np.ndarray, inside: np.ndarray, domain: str) -> None:
    """ValueError naming how many points lie outside ``domain`` and their bounding box."""
    out = ~inside
    n = int(out.sum())
    if n:
        raise ValueError(f"{n} of {len(X)} points lie outside {domain}; their bounding box: {_bbox_text(X[out])}")


# ------------------------------------------------------------------------------------------------------------
# The interface
@runtime_checkable
class SupportsDisplacementField(Protocol):
    """Anything with ``displacement_mm(X (N, 3)) -> (N, 3)`` and ``gradient(X (N, 3)) -> (N, 3, 3)``."""

    def displacement_mm(self, X_specimen_mm: np.ndarray) -> np.ndarray: ...

    def gradient(self, X_specimen_mm: np.ndarray) -> np.ndarray: ...


class DisplacementField(ABC):
    """A displacement field u(X) in the specimen frame (mm).

    Subclasses implement :meth:`displacement_mm` and :meth:`gradient`; points outside the field's domain
    raise a ValueError naming how many points and their bounding box. ``field(X)`` is
    ``field.displacement_mm(X)``, so a field can be passed wherever a callable ``u(X) -> (N, 3)`` is expected.
    """

    def __call__(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        return self.displacement_mm(X_specimen_mm)

    @abstractmethod
    def displacement_mm(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """Displacement u at material points.

        Parameters
        ----------
        X_specimen_mm : (N, 3) float, mm, specimen frame (undeformed positions)

        Returns
        -------
        (N, 3) float, mm
        """

    @abstractmethod
    def gradient(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """Displacement gradient ``H[n, i, j] = du_i / dX_j`` (dimensionless), (N, 3, 3)."""

    def contains(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """(N,) bool: which points lie in the field's domain (default: everywhere)."""
        return np.ones(len(_as_points(X_specimen_mm)), dtype=bool)

    def green_lagrange(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """Green-Lagrange strain ``E = (H + H^T + H^T H) / 2`` from :meth:`gradient`, (N, 3, 3), dimensionless."""
        H = self.gradient(X_specimen_mm)
        return 0.5 * (H + np.swapaxes(H, 1, 2) + np.einsum("nki,nkj->nij", H, H))


def _contains(field, X: np.ndarray) -> np.ndarray:
    """``field.contains`` where the field has one; a plain duck-typed field is taken as defined everywhere."""
    fn = getattr(field, "contains", None)
    return np.asarray(fn(X), dtype=bool) if fn is not None else np.ones(len(X), dtype=bool)


@dataclass(frozen=True, eq=False)
class RigidMotionField(DisplacementField):
    """A rigid motion ``X -> R (X - c) + c + t``: ``u = R (X - c) + c + t - X``, gradient ``R - I``.

    Parameters
    ----------
    R : (3, 3) proper rotation
    t_mm : (3,) translation, mm
    centre_mm : (3,) centre of rotation, mm (default the origin)
    """

    R: np.ndarray
    t_mm: np.ndarray
    centre_mm: np.ndarray = (0.0, 0.0, 0.0)

    def __post_init__(self):
        R = np.array(self.R, dtype=float)
        t = np.array(self.t_mm, dtype=float).reshape(-1)
        c = np.array(self.centre_mm, dtype=float).reshape(-1)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("R must be a (3, 3) proper rotation matrix")
        if t.shape != (3,) or c.shape != (3,) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(c))):
            raise ValueError("t_mm and centre_mm must be finite 3-vectors in mm")
        for name, value in (("R", R), ("t_mm", t), ("centre_mm", c)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def displacement_mm(self, X_specimen_mm):
        X = _as_points(X_specimen_mm)
        return (X - self.centre_mm) @ self.R.T + self.centre_mm + self.t_mm - X

    def gradient(self, X_specimen_mm):
        X = _as_points(X_specimen_mm)
        return np.broadcast_to(self.R - np.eye(3), (len(X), 3, 3)).copy()


@dataclass(frozen=True, eq=False)
class ScaledField(DisplacementField):
    """``factor * u_base``: in linear elasticity a load state is the unit-load solution times the load."""

    base: SupportsDisplacementField
    factor: float

    def __post_init__(self):
        if not np.isfinite(self.factor):
            raise ValueError(f"factor must be finite, got {self.factor}")

    def displacement_mm(self, X_specimen_mm):
        return self.factor * np.asarray(self.base.displacement_mm(_as_points(X_specimen_mm)), dtype=float)

    def gradient(self, X_specimen_mm):
        return self.factor * np.asarray(self.base.gradient(_as_points(X_specimen_mm)), dtype=float)

    def contains(self, X_specimen_mm):
        return _contains(self.base, _as_points(X_specimen_mm))


@dataclass(frozen=True, eq=False)
class DifferenceField(DisplacementField):
    """``u_a - u_b``: the truth of a state relative to a (preloaded) reference state, to first order."""

    a: SupportsDisplacementField
    b: SupportsDisplacementField

    def displacement_mm(self, X_specimen_mm):
        X = _as_points(X_specimen_mm)
        return np.asarray(self.a.displacement_mm(X), float) - np.asarray(self.b.displacement_mm(X), float)

    def gradient(self, X_specimen_mm):
        X = _as_points(X_specimen_mm)
        return np.asarray(self.a.gradient(X), float) - np.asarray(self.b.gradient(X), float)

    def contains(self, X_specimen_mm):
        X = _as_points(X_specimen_mm)
        return _contains(self.a, X) & _contains(self.b, X)


# ------------------------------------------------------------------------------------------------------------
# Three-point bending: parameters and beam theory
@dataclass(frozen=True)
class ThreePointBending:
    """The three-point-bending test of the aluminium beam (defaults: ``BendingSpecimen``'s 120 x 30 x 10 mm).

    Two rollers under the bottom face (``y = +H/2``) at ``x = +-span/2``, the loading nose on the top face
    (``y = -H/2``) at ``x = 0`` pushing along +y. Contacts are smeared line loads, uniform over the full
    thickness: the nose a pressure over a strip ``nose_width_mm`` wide, each roller a pressure over a strip
    ``support_width_mm`` wide (see :func:`solve_three_point_bending`).

    Parameters
    ----------
    length_mm, height_mm, thickness_mm : beam size (x, y, z)
    span_mm : distance between the supports
    youngs_modulus_mpa, poisson_ratio : isotropic linear elasticity (aluminium 70 GPa, 0.33)
    nose_width_mm, support_width_mm : widths of the contact strips (along x)
    element_mm : target edge length of the FE mesh (triquadratic hexahedra)
    """

    length_mm: float = 120.0
    height_mm: float = 30.0
    thickness_mm: float = 10.0
    span_mm: float = 100.0
    youngs_modulus_mpa: float = 70_000.0
    poisson_ratio: float = 0.33
    nose_width_mm: float = 2.0
    support_width_mm: float = 2.0
    element_mm: float = 2.5

    def __post_init__(self):
        for name in ("length_mm", "height_mm", "thickness_mm", "span_mm", "youngs_modulus_mpa",
                     "nose_width_mm", "support_width_mm", "element_mm"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")
        if not -1.0 < self.poisson_ratio < 0.5:
            raise ValueError(f"poisson_ratio must be in (-1, 0.5), got {self.poisson_ratio}")
        if self.span_mm + self.support_width_mm > self.length_mm + 1e-9:
            raise ValueError(f"the support strips (span {self.span_mm} + width {self.support_width_mm} mm) must lie "
                             f"on the {self.length_mm} mm beam")
        if self.nose_width_mm / 2 >= self.span_mm / 2 - self.support_width_mm / 2:
            raise ValueError("the nose strip must not reach the support strips")

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def second_moment_mm4(self) -> float:
        """I = T H^3 / 12 about the neutral axis (z axis), mm^4."""
        return self.thickness_mm * self.height_mm ** 3 / 12.0

    @property
    def shear_modulus_mpa(self) -> float:
        return self.youngs_modulus_mpa / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def lame_mpa(self) -> tuple[float, float]:
        """(lambda, mu) Lame parameters, MPa."""
        E, nu = self.youngs_modulus_mpa, self.poisson_ratio
        return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _params(params: ThreePointBending | None, kwargs: dict) -> ThreePointBending:
    if params is not None and kwargs:
        raise TypeError("pass either params or keyword overrides, not both")
    return params if params is not None else ThreePointBending(**kwargs)


def timoshenko_shear_coefficient(poisson_ratio: float) -> float:
    """Timoshenko shear coefficient of a rectangular section, ``kappa = 10 (1 + nu) / (12 + 11 nu)`` (Cowper 1966)."""
    return 10.0 * (1.0 + poisson_ratio) / (12.0 + 11.0 * poisson_ratio)


def timoshenko_midspan_deflection_mm(load_N: float, params: ThreePointBending | None = None, *,
                                     shear: bool = True, **kwargs) -> float:
    """Mid-span deflection of a simply supported Timoshenko beam under a central point load.

    ``delta = P S^3 / (48 E I) + P S / (4 kappa G A)`` with the span S, ``I = T H^3 / 12``, ``A = T H``,
    ``G = E / (2 (1 + nu))`` and ``kappa = 10 (1 + nu) / (12 + 11 nu)`` (rectangle, Cowper).

    Parameters
    ----------
    load_N : total load P, N
    params : ThreePointBending, optional (or its fields as keyword overrides)
    shear : False gives the Euler-Bernoulli (bending) part alone

    Returns
    -------
    float, mm (positive: along +y, down)
    """
    p = _params(params, kwargs)
    bending = load_N * p.span_mm ** 3 / (48.0 * p.youngs_modulus_mpa * p.second_moment_mm4)
    if not shear:
        return bending
    kappa = timoshenko_shear_coefficient(p.poisson_ratio)
    return bending + load_N * p.span_mm / (4.0 * kappa * p.shear_modulus_mpa * p.thickness_mm * p.height_mm)


def beam_theory_bending_moment_Nmm(x_mm, load_N: float, params: ThreePointBending | None = None,
                                   **kwargs) -> np.ndarray:
    """Sagging bending moment ``M(x) = P/2 (S/2 - |x|)`` between the supports, 0 outside, N mm."""
    p = _params(params, kwargs)
    x = np.abs(np.asarray(x_mm, dtype=float))
    return np.where(x <= p.span_mm / 2, 0.5 * load_N * (p.span_mm / 2 - x), 0.0)


def beam_theory_outer_fibre_strain(x_mm, load_N: float, params: ThreePointBending | None = None,
                                   **kwargs) -> np.ndarray:
    """Axial strain of the bottom fibre (``y = +H/2``, tension) from beam theory, ``M(x) c / (E I)``, c = H/2.

    The top fibre (``y = -H/2``) has the opposite sign (compression). Same shape as ``x_mm``, dimensionless.
    """
    p = _params(params, kwargs)
    M = beam_theory_bending_moment_Nmm(x_mm, load_N, p)
    return M * (p.height_mm / 2) / (p.youngs_modulus_mpa * p.second_moment_mm4)


# ------------------------------------------------------------------------------------------------------------
# Three-point bending: the finite-element solution
def _axis_nodes(breaks, element_mm: float) -> np.ndarray:
    """Node coordinates through every break point, each interval cut into equal elements <= element_mm."""
    breaks = np.unique(np.asarray(breaks, dtype=float))
    nodes = [breaks[:1]]
    for a, b in zip(breaks[:-1], breaks[1:]):
        n = max(1, int(np.ceil((b - a) / element_mm - 1e-9)))
        nodes.append(np.linspace(a, b, n + 1)[1:])
    return np.concatenate(nodes)


def _elasticity_matrix(basis, lam: float, mu: float):
    """Isotropic stiffness matrix of a scalar H1 basis, component-blocked DOFs ``[u_x | u_y | u_z]``.

    Same operator as ``skfem.models.elasticity.linear_elasticity`` on ``ElementVector``, assembled from the
    six scalar matrices ``A_ab[i, j] = int d_a phi_i d_b phi_j``:
    ``K_ab = lam A_ab + mu A_ba + mu delta_ab (A_xx + A_yy + A_zz)``. Why: scikit-fem assembles one Python
    kernel call per local basis pair, 81^2 for the vector 27-node hexahedron against 6 x 27^2 here (~25x faster).
    """
    import scipy.sparse as sp
    from skfem import BilinearForm, asm

    A = {}
    for a in range(3):
        for b in range(a, 3):
            @BilinearForm
            def form(u, v, w, a=a, b=b):
                return u.grad[b] * v.grad[a]
            A[a, b] = asm(form, basis).tocsr()

    def Aab(a, b):
        return A[a, b] if a <= b else A[b, a].T.tocsr()

    lap = Aab(0, 0) + Aab(1, 1) + Aab(2, 2)
    blocks = [[lam * Aab(a, b) + mu * Aab(b, a) + (mu * lap if a == b else 0.0) for b in range(3)]
              for a in range(3)]
    return sp.bmat(blocks, format="csr")


#: Public name of the isotropic stiffness assembly (the specimen catalog solves with it too).
elasticity_matrix = _elasticity_matrix


def _lagrange2(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """1-D quadratic Lagrange basis on nodes 0, 1/2, 1 and its derivative, each (N, 3)."""
    return (np.stack([2 * (t - 0.5) * (t - 1), -4 * t * (t - 1), 2 * t * (t - 0.5)], axis=1),
            np.stack([4 * t - 3, 4 - 8 * t, 4 * t - 1], axis=1))


def _gauss_composite(a: float, b: float, n_intervals: int, order: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre points and weights on [a, b]."""
    g, w = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(a, b, n_intervals + 1)
    half = 0.5 * np.diff(edges)
    mid = 0.5 * (edges[1:] + edges[:-1])
    return (mid[:, None] + half[:, None] * g).ravel(), (half[:, None] * w).ravel()


class ThreePointBendingSolution(DisplacementField):
    """The FE solution of :class:`ThreePointBending` for a total load of **1 N** (scale it for other loads).

    A quarter model (``0 <= x <= L/2``, ``0 <= z <= T/2``) is solved; the field is evaluated anywhere in the
    solid ``|x| <= L/2, |y| <= H/2, 0 <= z <= T`` by mirroring (``u_x`` odd in x, ``u_z`` odd about
    ``z = T/2``), with the triquadratic shape functions of ``ElementHex2`` on the structured mesh: the element
    and its local coordinates follow from the node coordinates directly (no search).

    Attributes
    ----------
    params : ThreePointBending
    x_nodes_mm, y_nodes_mm, z_nodes_mm : element boundaries of the quarter mesh, mm
    n_dofs : number of unknowns of the quarter model
    solve_time_s : wall time of assembly + solve, s
    support_force_N : total upward force of the two supports (= the load, 1 N)
    ground_reaction_N : reaction at the one node that fixes the vertical translation (~0: the smeared contact
        loads balance the nose load exactly, so nothing else carries load)
    """

    load_N = 1.0

    def __init__(self, params: ThreePointBending, x_nodes_mm, y_nodes_mm, z_nodes_mm, U_grid_mm: np.ndarray,
                 n_dofs: int, solve_time_s: float, support_force_N: float, ground_reaction_N: float):
        self.params = params
        self.x_nodes_mm, self.y_nodes_mm, self.z_nodes_mm = (np.array(a, float) for a in
                                                             (x_nodes_mm, y_nodes_mm, z_nodes_mm))
        self._U = np.ascontiguousarray(U_grid_mm, dtype=float)       # (Gx, Gy, Gz, 3) on the 27-node grid
        self._Uflat = self._U.reshape(-1, 3)
        for a in (self.x_nodes_mm, self.y_nodes_mm, self.z_nodes_mm, self._U):
            a.setflags(write=False)
        self.n_dofs = int(n_dofs)
        self.solve_time_s = float(solve_time_s)
        self.support_force_N = float(support_force_N)
        self.ground_reaction_N = float(ground_reaction_N)

    def __repr__(self):
        return (f"ThreePointBendingSolution({self.params!r}, n_dofs={self.n_dofs}, "
                f"solve_time_s={self.solve_time_s:.2f})")

    # ---- domain and mirroring
    def _tolerance_mm(self) -> float:
        return 1e-9 * self.params.length_mm

    def contains(self, X_specimen_mm):
        X = _as_points(X_specimen_mm)
        p, tol = self.params, self._tolerance_mm()
        return ((np.abs(X[:, 0]) <= p.length_mm / 2 + tol) & (np.abs(X[:, 1]) <= p.height_mm / 2 + tol)
                & (X[:, 2] >= -tol) & (X[:, 2] <= p.thickness_mm + tol))

    def _check(self, X) -> np.ndarray:
        X = _as_points(X)
        p = self.params
        _raise_outside(X, self.contains(X), f"the {p.length_mm:g} x {p.height_mm:g} x {p.thickness_mm:g} mm beam "
                                            f"(|x| <= {p.length_mm / 2:g}, |y| <= {p.height_mm / 2:g}, "
                                            f"0 <= z <= {p.thickness_mm:g} mm)")
        return X

    def _evaluate(self, X: np.ndarray, gradient: bool, chunk: int = 65536) -> np.ndarray:
        X = self._check(X)
        out = np.empty((len(X), 3, 3) if gradient else (len(X), 3))
        for s in range(0, len(X), chunk):
            out[s:s + chunk] = self._evaluate_chunk(X[s:s + chunk], gradient)
        return out

    def _evaluate_chunk(self, X: np.ndarray, gradient: bool) -> np.ndarray:
        T = self.params.thickness_mm
        # Mirror into the quarter model: x -> |x| flips u_x, z -> T - z (z > T/2) flips u_z.
        sx = np.where(X[:, 0] < 0, -1.0, 1.0)
        sz = np.where(X[:, 2] > T / 2, -1.0, 1.0)
        q = [np.abs(X[:, 0]), X[:, 1], np.where(X[:, 2] > T / 2, T - X[:, 2], X[:, 2])]
        idx, L, dL = [], [], []
        for nodes, c in zip((self.x_nodes_mm, self.y_nodes_mm, self.z_nodes_mm), q):
            e = np.clip(np.searchsorted(nodes, c, side="right") - 1, 0, len(nodes) - 2)
            h = nodes[e + 1] - nodes[e]
            t = np.clip((c - nodes[e]) / h, 0.0, 1.0)      # clip: points within the tolerance outside
            li, dli = _lagrange2(t)
            idx.append(2 * e[:, None] + np.arange(3))
            L.append(li)
            dL.append(dli / h[:, None])
        Gy, Gz = self._U.shape[1], self._U.shape[2]
        flat = (idx[0][:, :, None, None] * Gy + idx[1][:, None, :, None]) * Gz + idx[2][:, None, None, :]
        V = self._Uflat[flat]                                   # (N, 3, 3, 3, 3): x, y, z node, component
        S = np.stack([sx, np.ones_like(sx), sz], axis=1)
        if not gradient:
            u = np.einsum("nabci,na,nb,nc->ni", V, L[0], L[1], L[2], optimize=True)
            return u * S
        H = np.empty((len(X), 3, 3))
        for j, (fx, fy, fz) in enumerate(((dL[0], L[1], L[2]), (L[0], dL[1], L[2]), (L[0], L[1], dL[2]))):
            H[:, :, j] = np.einsum("nabci,na,nb,nc->ni", V, fx, fy, fz, optimize=True)
        return H * S[:, :, None] * S[:, None, :]                # H = S H' S for the reflection X' = S X + b

    def displacement_mm(self, X_specimen_mm):
        """Displacement for 1 N (see :class:`DisplacementField`); raises ValueError outside the beam."""
        return self._evaluate(X_specimen_mm, gradient=False)

    def gradient(self, X_specimen_mm):
        """Exact gradient of the FE interpolant (piecewise triquadratic) for 1 N, (N, 3, 3)."""
        return self._evaluate(X_specimen_mm, gradient=True)

    # ---- export
    def full_grid(self, load_N: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The 27-node grid of the whole beam (mirrored): x, y, z node coordinates (mm) and U (Gx, Gy, Gz, 3) mm."""
        T = self.params.thickness_mm
        xq, yq, zq = (_fine(a) for a in (self.x_nodes_mm, self.y_nodes_mm, self.z_nodes_mm))
        U = self._U * load_N
        Ux = np.concatenate([U[:0:-1] * np.array([-1.0, 1.0, 1.0]), U], axis=0)
        Uf = np.concatenate([Ux, Ux[:, :, -2::-1] * np.array([1.0, 1.0, -1.0])], axis=2)
        return (np.concatenate([-xq[:0:-1], xq]), yq, np.concatenate([zq, T - zq[-2::-1]]), Uf)

    def to_meshio(self, load_N: float = 1.0, displacement_name: str = "displacement"):
        """The whole beam as a meshio mesh of ``hexahedron27`` cells (VTK node order) with nodal displacements."""
        import meshio

        gx, gy, gz, U = self.full_grid(load_N)
        G = np.array([len(gx), len(gy), len(gz)])
        ne = (G - 1) // 2
        ex, ey, ez = np.meshgrid(*(np.arange(n) for n in ne), indexing="ij")
        offs = np.rint(2 * _REFERENCE["hexahedron27"].nodes).astype(int)        # (27, 3) in {0, 1, 2}
        ix = 2 * ex.reshape(-1, 1) + offs[:, 0]
        iy = 2 * ey.reshape(-1, 1) + offs[:, 1]
        iz = 2 * ez.reshape(-1, 1) + offs[:, 2]
        conn = (ix * G[1] + iy) * G[2] + iz
        X, Y, Z = np.meshgrid(gx, gy, gz, indexing="ij")
        points = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        return meshio.Mesh(points, [("hexahedron27", conn)], point_data={displacement_name: U.reshape(-1, 3)})


def _fine(nodes: np.ndarray) -> np.ndarray:
    """Corner nodes and edge midpoints, sorted: the 1-D coordinates of the 27-node grid."""
    out = np.empty(2 * len(nodes) - 1)
    out[0::2] = nodes
    out[1::2] = 0.5 * (nodes[1:] + nodes[:-1])
    return out


def solve_three_point_bending(params: ThreePointBending | None = None, **kwargs) -> ThreePointBendingSolution:
    """Solve the beam in three-point bending for a total load of 1 N (cached per parameter set).

    Model (3-D linear elasticity, scikit-fem):

    * **Element**: ``ElementHex2`` (triquadratic, 27 nodes) on a structured ``MeshHex`` of edge
      <= ``element_mm``, with nodes on the strip edges so that every strip is a whole number of elements.
    * **Symmetry**: quarter model ``0 <= x <= L/2``, ``0 <= z <= T/2`` with ``u_x = 0`` on ``x = 0`` and
      ``u_z = 0`` on ``z = T/2`` (exact: geometry, material and loads are symmetric in x and about mid-thickness).
    * **Nose**: uniform pressure ``P / (w_nose T)`` along +y on the top face, ``|x| <= w_nose/2``, full thickness.
    * **Supports**: frictionless rollers as uniform upward pressures ``(P/2) / (w_sup T)`` on the bottom face,
      ``|x -+ S/2| <= w_sup/2``, full thickness; the one remaining rigid motion (translation along y) is fixed
      at a single node and then removed so that the mean ``u_y`` over each support strip is 0. So each support
      transmits only a vertical force (its net u_y is held), is free to slide in x and to rotate. Why not fix
      ``u_y`` at every node of the strip: that rigid flat clamps the beam's rotation (it can pull down at one
      edge); on a span/height-20 beam it cut the span moment by 16 %.
    * **Material**: isotropic, E and nu of ``params``; small strains.

    Returns
    -------
    ThreePointBendingSolution
        The 1 N field; evaluate it anywhere in the solid. Cached per parameter set (8 most recent).
    """
    return _solve_cached(_params(params, kwargs))


@functools.lru_cache(maxsize=8)
def _solve_cached(p: ThreePointBending) -> ThreePointBendingSolution:
    from skfem import Basis, ElementHex2, FacetBasis, LinearForm, MeshHex, asm, condense, solve

    t0 = time.perf_counter()
    L, H, T, S = p.length_mm, p.height_mm, p.thickness_mm, p.span_mm
    wn, ws = p.nose_width_mm, p.support_width_mm
    xn = _axis_nodes([0.0, wn / 2, S / 2 - ws / 2, S / 2 + ws / 2, L / 2], p.element_mm)
    yn = _axis_nodes([-H / 2, H / 2], p.element_mm)
    zn = _axis_nodes([0.0, T / 2], p.element_mm)
    mesh = MeshHex.init_tensor(xn, yn, zn)
    elem = ElementHex2()
    basis = Basis(mesh, elem, intorder=4)      # 3 Gauss points per direction: exact for box Q2 stiffness
    n = basis.N
    K = _elasticity_matrix(basis, *p.lame_mpa)

    tol = 1e-9 * L
    nose = mesh.facets_satisfying(lambda x: (np.abs(x[1] + H / 2) < tol) & (x[0] < wn / 2))
    sup = mesh.facets_satisfying(lambda x: (np.abs(x[1] - H / 2) < tol) & (np.abs(x[0] - S / 2) < ws / 2))

    @LinearForm
    def unit(v, w):
        return v

    # Quarter model: the nose strip half carries P/4, the support strip (full width, half thickness) P/4 too.
    w_nose = asm(unit, FacetBasis(mesh, elem, facets=nose, intorder=4))
    w_sup = asm(unit, FacetBasis(mesh, elem, facets=sup, intorder=4))
    f = np.zeros(3 * n)
    f[n:2 * n] = w_nose / (wn * T) - w_sup * (0.5 / (ws * T))

    sym_x = basis.get_dofs(lambda x: np.abs(x[0]) < tol).all()
    sym_z = basis.get_dofs(lambda x: np.abs(x[2] - T / 2) < tol).all()
    centre = np.array([[S / 2], [H / 2], [T / 2]])
    ground = int(np.argmin(np.linalg.norm(basis.doflocs - centre, axis=0)))
    D = np.unique(np.concatenate([sym_x, [n + ground], 2 * n + sym_z]))
    u = solve(*condense(K, f, D=D))
    u[n:2 * n] -= (w_sup @ u[n:2 * n]) / w_sup.sum()     # translation along y: zero energy, exact shift
    ground_reaction = float((K @ u - f)[n + ground])

    # Scalar DOF locations -> indices on the 27-node grid.
    grids = [_fine(a) for a in (xn, yn, zn)]
    ijk = []
    for g, c in zip(grids, basis.doflocs):
        i = np.clip(np.searchsorted(g, c), 0, len(g) - 1)
        i = np.where((i > 0) & (np.abs(g[i - 1] - c) < np.abs(g[i] - c)), i - 1, i)
        if np.max(np.abs(g[i] - c)) > tol:
            raise RuntimeError("scikit-fem DOF locations do not lie on the 27-node grid")
        ijk.append(i)
    U = np.full((len(grids[0]), len(grids[1]), len(grids[2]), 3), np.nan)
    U[ijk[0], ijk[1], ijk[2]] = u.reshape(3, n).T
    if np.isnan(U).any():
        raise RuntimeError("the 27-node grid is not filled by the scikit-fem DOFs")
    return ThreePointBendingSolution(p, xn, yn, zn, U, n_dofs=3 * n - len(D), solve_time_s=time.perf_counter() - t0,
                                     support_force_N=4 * 0.5 / (ws * T) * float(w_sup.sum()),
                                     ground_reaction_N=4 * ground_reaction)


def three_point_bending_field(load_N: float, params: ThreePointBending | None = None, **kwargs) -> ScaledField:
    """The beam's displacement field under a total load ``load_N`` (N): the cached 1 N solution times the load.

    ``params`` or keyword overrides of :class:`ThreePointBending` (e.g. ``element_mm=5``). The default
    (2.5 mm elements, ~20 000 unknowns) solves in about 2 s on one core, once per process.
    """
    if not np.isfinite(load_N):
        raise ValueError(f"load_N must be finite, got {load_N}")
    return ScaledField(solve_three_point_bending(_params(params, kwargs)), float(load_N))


def _thickness_mean_uy(field, x_mm: float, y_mm: float, T: float) -> float:
    z, w = _gauss_composite(0.0, T, 16)
    X = np.stack([np.full_like(z, x_mm), np.full_like(z, y_mm), z], axis=1)
    return float(w @ np.asarray(field.displacement_mm(X))[:, 1] / T)


def fe_midspan_deflection_mm(field: SupportsDisplacementField, params: ThreePointBending | None = None,
                             **kwargs) -> dict:
    """Mid-span deflection of a bending field, several ways (all u_y averaged over the thickness, mm).

    Returns
    -------
    dict
        ``midspan_deflection_mm``: u_y on the neutral axis (y = 0) at x = 0 minus the mean u_y on the neutral
        axis over the support lines x = +-S/2: the beam's deflection without the local contact indentation
        (the quantity beam theory predicts). ``neutral_axis_midspan_mm``: u_y on the neutral axis at x = 0
        (raw: relative to the support strips, whose mean u_y is 0, so it includes the support indentation).
        ``neutral_axis_supports_mm``: that mean over the support lines. ``load_line_mm``: u_y of the top face
        at x = 0 (raw: includes the nose indentation too).
    """
    p = _params(params, kwargs)
    T, S, H = p.thickness_mm, p.span_mm, p.height_mm
    mid = _thickness_mean_uy(field, 0.0, 0.0, T)
    sup = 0.5 * (_thickness_mean_uy(field, S / 2, 0.0, T) + _thickness_mean_uy(field, -S / 2, 0.0, T))
    return {"midspan_deflection_mm": mid - sup, "neutral_axis_midspan_mm": mid, "neutral_axis_supports_mm": sup,
            "load_line_mm": _thickness_mean_uy(field, 0.0, -H / 2, T)}


def section_resultants(field: SupportsDisplacementField, x_mm: float, params: ThreePointBending | None = None,
                       **kwargs) -> dict:
    """Force resultants on the cross-section at ``x_mm`` from the field's stress (isotropic Hooke, small strain).

    Returns
    -------
    dict
        ``axial_N`` = int sigma_xx dA, ``shear_N`` = int sigma_xy dA, ``moment_Nmm`` = int sigma_xx y dA
        (sagging positive: y points down, so tension at the bottom is positive). Beam statics:
        0, ``-sign(x) P/2`` and ``P/2 (S/2 - |x|)`` between the supports.
    """
    p = _params(params, kwargs)
    lam, mu = p.lame_mpa
    y, wy = _gauss_composite(-p.height_mm / 2, p.height_mm / 2, 24)
    z, wz = _gauss_composite(0.0, p.thickness_mm, 16)
    Y, Z = np.meshgrid(y, z, indexing="ij")
    W = np.outer(wy, wz).ravel()
    X = np.stack([np.full(Y.size, float(x_mm)), Y.ravel(), Z.ravel()], axis=1)
    Hg = np.asarray(field.gradient(X))
    eps = 0.5 * (Hg + np.swapaxes(Hg, 1, 2))
    sxx = lam * np.trace(eps, axis1=1, axis2=2) + 2 * mu * eps[:, 0, 0]
    sxy = 2 * mu * eps[:, 0, 1]
    return {"axial_N": float(W @ sxx), "shear_N": float(W @ sxy), "moment_Nmm": float(W @ (sxx * X[:, 1]))}


def three_point_bending_report(params: ThreePointBending | None = None, load_N: float = 1.0,
                               refinement_element_mm: tuple[float, float] = (5.0, 2.5),
                               strain_x_mm: tuple[float, ...] = (-25.0, 25.0)) -> dict:
    """The FE solution against beam theory, and a mesh-refinement pair, as a plain dict (for a report).

    Parameters
    ----------
    params : the model (default :class:`ThreePointBending`)
    load_N : total load, N (everything is linear in it)
    refinement_element_mm : two element sizes (coarse, fine) solved with otherwise the same ``params``
    strain_x_mm : positions of the outer-fibre strain comparison (front face, top and bottom edges)

    Returns
    -------
    dict with ``params``, ``load_N``, ``solve_time_s``, ``n_dofs``, ``timoshenko`` (bending, shear, total mm,
    kappa), ``fe`` (the deflections of :func:`fe_midspan_deflection_mm` and their errors against Timoshenko in
    %), ``outer_fibre_strain`` (list of {x_mm, y_mm, fe, theory, error_pct}), ``section`` (list of resultants
    against statics) and ``refinement`` (element sizes, deflections, change in %).
    """
    p = params if params is not None else ThreePointBending()
    sol = solve_three_point_bending(p)
    field = ScaledField(sol, load_N)
    bending = timoshenko_midspan_deflection_mm(load_N, p, shear=False)
    total = timoshenko_midspan_deflection_mm(load_N, p)
    fe = fe_midspan_deflection_mm(field, p)
    pct = {k.replace("_mm", "_vs_timoshenko_pct"): 100 * (v / total - 1) for k, v in fe.items()
           if k != "neutral_axis_supports_mm"}
    strains = []
    for x in strain_x_mm:
        th = float(beam_theory_outer_fibre_strain(x, load_N, p))
        for y, sign in ((-p.height_mm / 2, -1.0), (p.height_mm / 2, 1.0)):
            e = float(field.gradient(np.array([[x, y, 0.0]]))[0, 0, 0])
            strains.append({"x_mm": x, "y_mm": y, "fe": e, "theory": sign * th,
                            "error_pct": 100 * (e / (sign * th) - 1)})
    section = []
    for x in strain_x_mm:
        r = section_resultants(field, x, p)
        r.update(x_mm=x, moment_theory_Nmm=float(beam_theory_bending_moment_Nmm(x, load_N, p)),
                 shear_theory_N=-np.sign(x) * load_N / 2)
        section.append(r)
    ref = [solve_three_point_bending(ThreePointBending(**{**p.to_dict(), "element_mm": h}))
           for h in refinement_element_mm]
    ref_d = [fe_midspan_deflection_mm(ScaledField(s, load_N), p)["midspan_deflection_mm"] for s in ref]
    return {
        "params": p.to_dict(), "load_N": load_N, "solve_time_s": sol.solve_time_s, "n_dofs": sol.n_dofs,
        "timoshenko": {"bending_mm": bending, "shear_mm": total - bending, "total_mm": total,
                       "shear_coefficient": timoshenko_shear_coefficient(p.poisson_ratio)},
        "fe": {**fe, **pct, "support_force_N": sol.support_force_N * load_N,
               "ground_reaction_N": sol.ground_reaction_N * load_N},
        "outer_fibre_strain": strains,
        "section": section,
        "refinement": {"element_mm": list(refinement_element_mm), "midspan_deflection_mm": ref_d,
                       "change_pct": 100 * (ref_d[1] / ref_d[0] - 1), "n_dofs": [s.n_dofs for s in ref],
                       "solve_time_s": [s.solve_time_s for s in ref]},
    }


# ------------------------------------------------------------------------------------------------------------
# User FE results: reference elements (VTK / meshio node order)
@dataclass(frozen=True, eq=False)
class _RefElement:
    """A Lagrange-type reference element: node coordinates and the monomials spanning its shape functions.

    The shape functions are ``N(xi) = m(xi) @ C`` with ``C = V^-1``, ``V[i, k] = m_k(node_i)``: each is 1 at
    its node and 0 at the others, in exactly the polynomial space of the element, so any node order/space can
    be written down instead of hand-coding the functions.
    """

    name: str
    nodes: np.ndarray        # (nn, 3) reference coordinates, in the file's node order
    exponents: np.ndarray    # (nn, 3) monomial exponents
    kind: str                # "simplex", "cube" or "prism": the reference domain
    n_corners: int

    @functools.cached_property
    def coefficients(self) -> np.ndarray:
        V = np.prod(self.nodes[:, None, :] ** self.exponents[None, :, :], axis=2)
        return np.linalg.inv(V)

    def shape(self, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shape functions (P, nn) and their reference derivatives (P, nn, 3) at xi (P, 3)."""
        e = self.exponents.astype(int)
        P = len(xi)
        # Powers 0..2 of each coordinate and their derivatives, picked per monomial.
        pw = np.stack([np.ones_like(xi), xi, xi * xi], axis=2)                     # (P, 3, 3): dim, power
        dpw = np.stack([np.zeros_like(xi), np.ones_like(xi), 2 * xi], axis=2)
        f = [pw[:, d, e[:, d]] for d in range(3)]                                  # (P, nm) each
        g = [dpw[:, d, e[:, d]] for d in range(3)]
        m = f[0] * f[1] * f[2]
        dm = np.stack([g[0] * f[1] * f[2], f[0] * g[1] * f[2], f[0] * f[1] * g[2]], axis=1)   # (P, 3, nm)
        C = self.coefficients
        dN = (dm.reshape(3 * P, -1) @ C).reshape(P, 3, -1)
        return m @ C, np.swapaxes(dN, 1, 2)

    def violation(self, xi: np.ndarray) -> np.ndarray:
        """How far xi lies outside the reference domain (0 inside), (P,)."""
        neg = np.maximum(-xi, 0.0)
        if self.kind == "cube":
            return np.max(np.maximum(neg, xi - 1.0), axis=1)
        if self.kind == "simplex":
            return np.maximum(neg.max(axis=1), xi.sum(axis=1) - 1.0)
        return np.maximum.reduce([neg.max(axis=1), xi[:, 0] + xi[:, 1] - 1.0, xi[:, 2] - 1.0])

    @property
    def centre(self) -> np.ndarray:
        return self.nodes[: self.n_corners].mean(axis=0)


def _exps(max_each: int, max_total: int | None = None, extra=None) -> np.ndarray:
    e = [(a, b, c) for c in range(max_each + 1) for b in range(max_each + 1) for a in range(max_each + 1)
         if max_total is None or a + b + c <= max_total]
    return np.array(e if extra is None else [t for t in e if extra(t)], dtype=float)


_HEX8 = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
_HEX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
_HEX20 = np.concatenate([_HEX8, [(_HEX8[a] + _HEX8[b]) / 2 for a, b in _HEX_EDGES]])
# VTK_TRIQUADRATIC_HEXAHEDRON: mid-face nodes of the -x, +x, -y, +y, -z, +z faces, then the centre.
_HEX27 = np.concatenate([_HEX20, [[0, .5, .5], [1, .5, .5], [.5, 0, .5], [.5, 1, .5], [.5, .5, 0], [.5, .5, 1],
                                  [.5, .5, .5]]])
_TET4 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
_TET10 = np.concatenate([_TET4, [(_TET4[a] + _TET4[b]) / 2 for a, b in
                                 [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]]])
_WEDGE6 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], float)


_REFERENCE = {r.name: r for r in [
    _RefElement("tetra", _TET4, _exps(1, 1), "simplex", 4),
    _RefElement("tetra10", _TET10, _exps(2, 2), "simplex", 4),
    _RefElement("hexahedron", _HEX8, _exps(1), "cube", 8),
    # Serendipity space: the Q2 monomials with at most one exponent equal to 2 (20 of them).
    _RefElement("hexahedron20", _HEX20, _exps(2, extra=lambda t: sum(a == 2 for a in t) <= 1), "cube", 8),
    _RefElement("hexahedron27", _HEX27, _exps(2), "cube", 8),
    _RefElement("wedge", _WEDGE6, np.array([(a, b, c) for c in (0, 1) for a, b in ((0, 0), (1, 0), (0, 1))], float),
                "prism", 6),
]}
_ALIASES = {"tetra4": "tetra", "hexahedron8": "hexahedron"}
#: Cell types whose node order in Exodus II differs from VTK's for the same meshio name (meshio passes them on
#: unchanged), so they are refused from Exodus files.
_EXODUS_REORDERED = {"hexahedron20", "hexahedron27"}
#: The reference volume elements by meshio cell name (public: the surface of a volume mesh is read from them).
REFERENCE_ELEMENTS = _REFERENCE


class FEMeshField(DisplacementField):
    """Nodal displacements on a volume mesh, interpolated with each element's own shape functions.

    Supported cells (VTK node order, as meshio uses it): ``tetra`` (4), ``tetra10``, ``hexahedron`` (8),
    ``hexahedron20`` (serendipity), ``hexahedron27``, ``wedge`` (6); isoparametric, so curved quadratic
    elements work. Other cells (surfaces, lines, unsupported volume types) are ignored; a mesh with no
    supported volume cell is refused. A point is located by a k-d tree over element centres and a Newton
    inversion of the element map; points in no element raise ValueError (see :meth:`contains`).

    Parameters
    ----------
    points_mm : (P, 3) node coordinates in the specimen frame, mm
    cells : dict cell type -> (E, nn) int node indices
    displacement_mm : (P, 3) nodal displacements, mm
    source : a name for messages (the file)
    """

    #: Tolerance on the reference coordinates for "inside an element" (relative to the element size).
    INSIDE_TOL = 1e-8

    def __init__(self, points_mm, cells: dict, displacement_mm, source: str = "<mesh>"):
        from scipy.spatial import cKDTree

        self.source = str(source)
        P = np.asarray(points_mm, dtype=float)
        U = np.asarray(displacement_mm, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or U.shape != P.shape:
            raise ValueError(f"{self.source}: points (P, 3) and displacement (P, 3) needed, got {P.shape} and "
                             f"{U.shape}")
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(U))):
            raise ValueError(f"{self.source}: node coordinates and displacements must be finite")
        self.points_mm, self.nodal_displacement_mm = P, U
        self.cells: dict[str, np.ndarray] = {}
        for name, conn in cells.items():
            conn = np.asarray(conn, dtype=np.int64)
            ref = _REFERENCE[name]
            if conn.ndim != 2 or conn.shape[1] != len(ref.nodes) or conn.min() < 0 or conn.max() >= len(P):
                raise ValueError(f"{self.source}: bad {name} connectivity of shape {conn.shape}")
            if len(conn):
                self.cells[name] = conn
        if not self.cells:
            raise ValueError(f"{self.source}: no volume cells")
        # A flat list of all elements (type, row) for the k-d tree over element centres.
        self._types = list(self.cells)
        self._elem_type = np.concatenate([np.full(len(c), k) for k, c in enumerate(self.cells.values())])
        self._elem_row = np.concatenate([np.arange(len(c)) for c in self.cells.values()])
        centres, radii, lo, hi = [], [], [], []
        for name, conn in self.cells.items():
            Xe = P[conn]
            c = Xe[:, : _REFERENCE[name].n_corners].mean(axis=1)
            centres.append(c)
            radii.append(np.linalg.norm(Xe - c[:, None], axis=2).max(axis=1))
            # Node bounding box, enlarged: curved quadratic elements bulge a little past their nodes.
            a, b = Xe.min(axis=1), Xe.max(axis=1)
            pad = 0.1 * (b - a).max(axis=1, keepdims=True) + 1e-9 * (1 + np.abs(Xe).max(axis=(1, 2)))[:, None]
            lo.append(a - pad)
            hi.append(b + pad)
        self._centres = np.concatenate(centres)
        self._lo, self._hi = np.concatenate(lo), np.concatenate(hi)
        self._radius = 1.25 * float(np.concatenate(radii).max())   # margin: curved elements bulge past nodes
        self._tree = cKDTree(self._centres)
        for a in (self.points_mm, self.nodal_displacement_mm):
            a.setflags(write=False)

    def __repr__(self):
        counts = ", ".join(f"{len(c)} {n}" for n, c in self.cells.items())
        return f"FEMeshField({self.source!r}: {len(self.points_mm)} nodes, {counts})"

    # ---- reading
    @classmethod
    def from_meshio(cls, mesh, displacement_name: str | tuple[str, str, str] | None = None, *,
                    source: str = "<meshio.Mesh>", scale_to_mm: float = 1.0,
                    R_specimen_from_mesh=None, t_specimen_from_mesh_mm=None,
                    exodus: bool = False) -> "FEMeshField":
        """A field from a ``meshio.Mesh``; see :meth:`from_file` for the parameters."""
        cells: dict[str, list] = {}
        found = []
        for block in mesh.cells:
            name = _ALIASES.get(block.type, block.type)
            found.append(block.type)
            if name in _REFERENCE:
                if exodus and name in _EXODUS_REORDERED:
                    raise ValueError(f"{source}: {name} cells from Exodus are not supported (Exodus orders their "
                                     f"mid-edge/face nodes differently from VTK and meshio does not reorder them); "
                                     f"export VTU instead")
                cells.setdefault(name, []).append(np.asarray(block.data))
        if not cells:
            raise ValueError(f"{source}: no volume cells of a supported type ({', '.join(sorted(_REFERENCE))}); "
                             f"the file has: {', '.join(sorted(set(found))) or 'no cells'}")
        U = displacement_array(mesh.point_data, len(mesh.points), displacement_name, source)
        s = float(scale_to_mm)
        if not (np.isfinite(s) and s > 0):
            raise ValueError(f"scale_to_mm must be positive, got {scale_to_mm}")
        R = np.eye(3) if R_specimen_from_mesh is None else np.asarray(R_specimen_from_mesh, dtype=float)
        t = np.zeros(3) if t_specimen_from_mesh_mm is None else np.asarray(t_specimen_from_mesh_mm, float).reshape(3)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("R_specimen_from_mesh must be a (3, 3) proper rotation")
        P = np.asarray(mesh.points, dtype=float)
        if P.shape[1] == 2:
            raise ValueError(f"{source}: a 2-D mesh; a volume mesh is needed")
        return cls(s * P @ R.T + t, {k: np.concatenate(v) for k, v in cells.items()}, s * U @ R.T, source=source)

    @classmethod
    def from_file(cls, path, displacement_name: str | tuple[str, str, str] | None = None, *,
                  scale_to_mm: float = 1.0, R_specimen_from_mesh=None, t_specimen_from_mesh_mm=None,
                  file_format: str | None = None) -> "FEMeshField":
        """Read nodal displacements on a volume mesh with meshio.

        Parameters
        ----------
        path : a mesh file meshio reads (tested: VTU, legacy VTK; Exodus ``.e``/``.exo`` needs netCDF4, and
            meshio reads only its first time step)
        displacement_name : point-data array (P, 3), or three scalar arrays (x, y, z); None picks the one
            vector array named like a displacement (``displacement``, ``disp``, ``u``, ...) or the only
            (P, 3) array
        scale_to_mm : file length unit in mm (1000 for metres): applied to coordinates and displacements
        R_specimen_from_mesh, t_specimen_from_mesh_mm : the file's frame in the specimen frame,
            ``X_specimen = R (s X_file) + t``, displacements rotated by R (default identity)
        file_format : meshio's format name, if the extension does not tell

        Raises
        ------
        ValueError
            The file is not a mesh meshio can read, has no supported volume cells, or the displacement array
            is missing or ambiguous (the message names the file and the available arrays).
        """
        import meshio

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: no such file")
        try:
            mesh = meshio.read(path, file_format=file_format)
        except (Exception, SystemExit) as exc:   # meshio raises many types, and exits on some unreadable files
            raise ValueError(f"{path}: not a mesh file meshio can read ({type(exc).__name__}: {exc})") from exc
        exodus = (file_format or "").lower() == "exodus" or path.lower().endswith((".e", ".exo", ".ex2"))
        return cls.from_meshio(mesh, displacement_name, source=path, scale_to_mm=scale_to_mm,
                               R_specimen_from_mesh=R_specimen_from_mesh,
                               t_specimen_from_mesh_mm=t_specimen_from_mesh_mm, exodus=exodus)

    # ---- location and evaluation
    def _newton(self, ref: _RefElement, Xe: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference coordinates of points p (M, 3) in elements with nodes Xe (M, nn, 3), and the violation."""
        xi = np.broadcast_to(ref.centre, p.shape).copy()
        converged = np.zeros(len(p), dtype=bool)
        active = np.arange(len(p))
        for _ in range(30):
            N, dN = ref.shape(xi[active])
            Xa = Xe[active]
            r = p[active] - np.einsum("ma,mak->mk", N, Xa)
            J = np.einsum("mad,mak->mkd", dN, Xa)
            good = np.abs(np.linalg.det(J)) > 1e-300
            J[~good] = np.eye(3)
            step = np.linalg.solve(J, r[:, :, None])[:, :, 0]
            xi[active] = np.clip(xi[active] + step, -1.0, 2.0)      # keep far-off candidates from diverging
            done = np.abs(step).max(axis=1) < 1e-13
            converged[active[done & good]] = True
            # Drop converged, degenerate and clearly-outside candidates (stuck at the clip box).
            stuck = np.any((xi[active] <= -1.0) | (xi[active] >= 2.0), axis=1)
            active = active[~done & good & ~stuck]
            if not len(active):
                break
        viol = ref.violation(xi)
        return xi, np.where(converged, viol, np.inf)

    def _test(self, X: np.ndarray, elems: np.ndarray, best: dict) -> None:
        """Try global elements ``elems`` (M,) for points ``X`` (M, 3); keep the least violating per point."""
        # Cheap rejection first: the point must lie in the element's (enlarged) bounding box.
        inbox = np.all((X >= self._lo[elems]) & (X <= self._hi[elems]), axis=1)
        for k, name in enumerate(self._types):
            sel = np.flatnonzero(inbox & (self._elem_type[elems] == k))
            if not len(sel):
                continue
            ref = _REFERENCE[name]
            rows = self._elem_row[elems[sel]]
            xi, viol = self._newton(ref, self.points_mm[self.cells[name][rows]], X[sel])
            better = viol < best["viol"][sel]
            s = sel[better]
            best["viol"][s], best["type"][s], best["row"][s], best["xi"][s] = viol[better], k, rows[better], xi[better]

    def _locate(self, X: np.ndarray, chunk: int = 20000) -> dict:
        n = len(X)
        best = {"viol": np.full(n, np.inf), "type": np.full(n, -1), "row": np.full(n, -1), "xi": np.zeros((n, 3))}
        k = min(8, len(self._centres))
        for s in range(0, n, chunk):
            idx = np.arange(s, min(n, s + chunk))
            _, cand = self._tree.query(X[idx], k=k)
            cand = cand.reshape(len(idx), -1)
            for j in range(cand.shape[1]):       # nearest centres first; stop trying for found points
                todo = idx[best["viol"][idx] > self.INSIDE_TOL]
                if not len(todo):
                    break
                sub = {key: v[todo] for key, v in best.items()}
                self._test(X[todo], cand[todo - s, j], sub)
                for key in best:
                    best[key][todo] = sub[key]
        # Fallback: every element whose bounding sphere can hold the point.
        todo = np.flatnonzero(best["viol"] > self.INSIDE_TOL)
        if len(todo):
            lists = self._tree.query_ball_point(X[todo], r=self._radius)
            counts = np.array([len(c) for c in lists])
            if counts.sum():
                pts = np.repeat(todo, counts)
                elems = np.concatenate([np.asarray(c, dtype=np.int64) for c in lists if len(c)])
                sub = {"viol": np.full(len(pts), np.inf), "type": np.full(len(pts), -1),
                       "row": np.full(len(pts), -1), "xi": np.zeros((len(pts), 3))}
                self._test(X[pts], elems, sub)
                order = np.lexsort((sub["viol"], pts))           # per point, least violation first
                first = order[np.r_[True, pts[order][1:] != pts[order][:-1]]]
                for key in best:
                    better = sub["viol"][first] < best["viol"][pts[first]]
                    best[key][pts[first][better]] = sub[key][first][better]
        best["inside"] = best["viol"] <= self.INSIDE_TOL
        return best

    def contains(self, X_specimen_mm):
        """(N,) bool: points inside some element (within ``INSIDE_TOL`` of its reference domain)."""
        return self._locate(_as_points(X_specimen_mm))["inside"]

    def _evaluate(self, X_specimen_mm, gradient: bool) -> np.ndarray:
        X = _as_points(X_specimen_mm)
        loc = self._locate(X)
        _raise_outside(X, loc["inside"], f"the mesh of {self.source}")
        out = np.empty((len(X), 3, 3) if gradient else (len(X), 3))
        for k, name in enumerate(self._types):
            sel = np.flatnonzero(loc["type"] == k)
            if not len(sel):
                continue
            conn = self.cells[name][loc["row"][sel]]
            N, dN = _REFERENCE[name].shape(loc["xi"][sel])
            Ue = self.nodal_displacement_mm[conn]
            if not gradient:
                out[sel] = np.einsum("ma,mai->mi", N, Ue)
                continue
            J = np.einsum("mad,mak->mkd", dN, self.points_mm[conn])          # dx_k / dxi_d
            Gref = np.einsum("mad,mai->mid", dN, Ue)                         # du_i / dxi_d
            out[sel] = np.einsum("mid,mdj->mij", Gref, np.linalg.inv(J))
        return out

    def displacement_mm(self, X_specimen_mm):
        return self._evaluate(X_specimen_mm, gradient=False)

    def gradient(self, X_specimen_mm):
        """Gradient of the interpolant, ``dN/dX = dN/dxi J^-1`` (exact for it), (N, 3, 3)."""
        return self._evaluate(X_specimen_mm, gradient=True)

    def check_covers_face(self, length_mm: float, height_mm: float, n: int = 121, z_mm: float = 0.0) -> "FEMeshField":
        """:func:`check_covers_face` on this field; returns self."""
        check_covers_face(self, length_mm, height_mm, n=n, z_mm=z_mm)
        return self


_DISPLACEMENT_NAMES = re.compile(r"^(u|d|disp|displ|displacement|displacements|deformation|dis)$", re.IGNORECASE)
_COMPONENT = re.compile(r"^(.*?)[_\-:. ]?([xyzXYZ])$")
#: Public: how a scalar field names its component (``disp_x``, ``ux``, ``U:X``).
COMPONENT_PATTERN = _COMPONENT


def displacement_field_name(point_data: dict, n_points: int, name, source: str) -> str | tuple[str, str, str]:
    """The nodal displacement among meshio-style point data: ``name`` checked (a (P, 3) array, or three scalar
    arrays x, y, z), or, for None, the one vector array named like a displacement (``displacement``, ``disp``,
    ``u``, ...), the one such scalar triplet (``disp_x``, ``disp_y``, ``disp_z``) or the only (P, 3) array.

    Raises ValueError naming ``source`` and listing the available arrays when it is missing or ambiguous."""
    def describe():
        items = [f"{k} {tuple(np.shape(v))}" for k, v in point_data.items()]
        return ", ".join(items) if items else "none"

    def vector(key):
        shape = np.shape(point_data[key])
        if shape != (n_points, 3):
            raise ValueError(f"{source}: point data {key!r} has shape {shape}, not ({n_points}, 3) displacements; "
                             f"available point data: {describe()}")
        return key

    if isinstance(name, (tuple, list)):
        missing = [k for k in name if k not in point_data]
        if len(name) != 3 or missing:
            raise ValueError(f"{source}: displacement components {tuple(name)} not found (missing {missing}); "
                             f"available point data: {describe()}")
        for k in name:
            if np.size(point_data[k]) != n_points:
                raise ValueError(f"{source}: point data {k!r} has {np.size(point_data[k])} values for {n_points} "
                                 f"nodes; available point data: {describe()}")
        return tuple(name)
    if name is not None:
        if name not in point_data:
            raise ValueError(f"{source}: no point data named {name!r}; available point data: {describe()}")
        return vector(name)
    vectors = [k for k, v in point_data.items() if np.shape(v) == (n_points, 3)]
    named = [k for k in vectors if _DISPLACEMENT_NAMES.match(k)]
    # Scalar triplets such as disp_x, disp_y, disp_z.
    groups: dict[str, dict[str, str]] = {}
    for k, v in point_data.items():
        m = _COMPONENT.match(k)
        if m and np.size(v) == n_points:
            groups.setdefault(m.group(1), {})[m.group(2).lower()] = k
    triplets = {b: (g["x"], g["y"], g["z"]) for b, g in groups.items() if set(g) == {"x", "y", "z"}}
    named_triplets = [b for b in triplets if _DISPLACEMENT_NAMES.match(b)]
    if len(named) == 1:
        return vector(named[0])
    if not named and len(named_triplets) == 1:
        return triplets[named_triplets[0]]
    if not named and not named_triplets and len(vectors) == 1:
        return vector(vectors[0])
    what = "ambiguous" if (len(named) > 1 or len(vectors) > 1 or len(named_triplets) > 1) else "missing"
    raise ValueError(f"{source}: nodal displacement {what}; name it (displacement_name=, or a specimen's field =) "
                     f"among the point data arrays (available point data: {describe()})")


def displacement_array(point_data: dict, n_points: int, name, source: str) -> np.ndarray:
    """The (P, 3) nodal displacement :func:`displacement_field_name` names, as float."""
    key = displacement_field_name(point_data, n_points, name, source)
    if isinstance(key, tuple):
        return np.stack([np.asarray(point_data[k], dtype=float).reshape(n_points) for k in key], axis=1)
    return np.asarray(point_data[key], dtype=float)



def check_covers_face(field: SupportsDisplacementField, length_mm: float, height_mm: float, n: int = 121,
                      z_mm: float = 0.0) -> None:
    """Refuse a field whose domain does not cover the specimen's front face.

    Samples the face ``|x| <= length/2, |y| <= height/2`` at ``z = z_mm`` on a grid of ``n`` points along x
    (and the same spacing along y, at least 3 points), edges included, and asks ``field.contains``.

    Raises
    ------
    ValueError
        Naming how many sample points are uncovered, their fraction and their bounding box (mm).
    """
    if not (length_mm > 0 and height_mm > 0 and n >= 2):
        raise ValueError("length_mm and height_mm must be positive and n >= 2")
    ny = max(3, int(round((n - 1) * height_mm / length_mm)) + 1)     # about the x spacing
    xs = np.linspace(-length_mm / 2, length_mm / 2, int(n))
    ys = np.linspace(-height_mm / 2, height_mm / 2, ny)
    Xg, Yg = np.meshgrid(xs, ys, indexing="ij")
    P = np.stack([Xg.ravel(), Yg.ravel(), np.full(Xg.size, float(z_mm))], axis=1)
    inside = _contains(field, P)
    if not inside.all():
        U = P[~inside]
        lo, hi = U.min(axis=0), U.max(axis=0)
        raise ValueError(
            f"{getattr(field, 'source', type(field).__name__)} does not cover the {length_mm:g} x {height_mm:g} mm "
            f"front face at z = {z_mm:g} mm: {len(U)} of {len(P)} sample points ({100 * len(U) / len(P):.1f} %) "
            f"are uncovered, in the region x in [{lo[0]:.6g}, {hi[0]:.6g}] mm, y in [{lo[1]:.6g}, {hi[1]:.6g}] mm")
