"""The aluminium beam of the paper's three-point bending test, solved by finite elements (truth side).

* :class:`ThreePointBending`: the beam, its material and load geometry (supports 100 mm apart, the loading nose at
  mid-span on the top face).
* :func:`solve_three_point_bending` / :func:`three_point_bending_field`: a 3-D linear-elastic finite-element
  solution (scikit-fem, triquadratic 27-node hexahedra) for 1 N, scaled by the load
  (:class:`scenes.deformation.displacement_field.ScaledField`), with :func:`timoshenko_midspan_deflection_mm`
  and :func:`beam_theory_outer_fibre_strain` to compare it with, and :func:`three_point_bending_report` for the
  figures (Timoshenko comparison, mesh refinement).

Specimen frame as :mod:`scenes.deformation.displacement_field`: origin at the centre of the speckled front face,
x along the length, y along the height pointing DOWN (top face ``y = -H/2``), z into the material (front face
``z = 0``, back face ``z = T``). scikit-fem is imported only where used, so importing this module stays cheap.
"""
from __future__ import annotations

import functools
import time
from dataclasses import asdict, dataclass

import numpy as np

from scenes.deformation.displacement_field import (DisplacementField, ScaledField, SupportsDisplacementField,
                                                   as_points, raise_outside)
from scenes.deformation.fe_elements import REFERENCE_ELEMENTS

__all__ = [
    "ThreePointBending", "ThreePointBendingSolution", "solve_three_point_bending", "three_point_bending_field",
    "timoshenko_shear_coefficient", "timoshenko_midspan_deflection_mm", "beam_theory_bending_moment_Nmm",
    "beam_theory_outer_fibre_strain", "fe_midspan_deflection_mm", "section_resultants",
    "three_point_bending_report", "elasticity_matrix",
]



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
        X = as_points(X_specimen_mm)
        p, tol = self.params, self._tolerance_mm()
        return ((np.abs(X[:, 0]) <= p.length_mm / 2 + tol) & (np.abs(X[:, 1]) <= p.height_mm / 2 + tol)
                & (X[:, 2] >= -tol) & (X[:, 2] <= p.thickness_mm + tol))

    def _check(self, X) -> np.ndarray:
        X = as_points(X)
        p = self.params
        raise_outside(X, self.contains(X), f"the {p.length_mm:g} x {p.height_mm:g} x {p.thickness_mm:g} mm beam "
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
        offs = np.rint(2 * REFERENCE_ELEMENTS["hexahedron27"].nodes).astype(int)        # (27, 3) in {0, 1, 2}
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
