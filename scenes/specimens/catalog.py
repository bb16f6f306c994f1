"""A small catalog of specimens with their finite-element solutions, written as files a user could have made.

Each specimen is a linear-elastic model solved with scikit-fem on curved 27-node hexahedra (isoparametric
``MeshHex2``: holes, notches and cylinders are curved, not faceted), one quarter or eighth by symmetry, mirrored
into the whole specimen and written as a ParaView ``.pvd`` collection of VTU files (``hexahedron27``, the
displacement as point data ``displacement`` in mm, one file per load step): what an FE user exports from their
own model. Every specimen's frame puts the face the cameras see at ``z = 0`` facing ``-z`` (the cylinder's
front line), the rest of the material at ``z > 0``, so a scenario needs no placement.

* :func:`plate_with_hole`: a square plate with a central circular hole, pulled along x (the classic stress
  concentration, Kirsch: 3x the remote stress at the hole's sides for an infinite plate);
* :func:`notched_coupon`: a coupon with two semicircular edge notches at mid-length, pulled along x;
* :func:`pressurised_cylinder`: a thick-walled tube (outer radius 57 mm) under internal pressure (Lame's solution
  is its check), axis along y;
* :func:`beam`: the three-point bending beam of :mod:`scenes.deformation.beam_bending`, as a file.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenes.deformation.fe_elements import REFERENCE_ELEMENTS
from scenes.deformation.beam_bending import elasticity_matrix


@dataclass
class FEResult:
    """A solved FE model: ``hexahedron27`` cells (VTK order), nodal displacements per load step (mm)."""

    name: str
    points_mm: np.ndarray
    cells: np.ndarray
    displacements_mm: np.ndarray           # (K, P, 3)
    times: np.ndarray                      # (K,) load factor or load, as 'load_unit' says
    load_unit: str
    info: dict = field(default_factory=dict)


def _lame(E: float, nu: float) -> tuple[float, float]:
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _curved_mesh(a, b, c, mapping):
    """An isoparametric 27-node mesh: the tensor grid of parameters (a, b, c) mapped node by node (mid nodes too)."""
    from skfem import MeshHex, MeshHex2

    m2 = MeshHex2.from_mesh(MeshHex.init_tensor(np.asarray(a, float), np.asarray(b, float), np.asarray(c, float)))
    return MeshHex2(np.asarray(mapping(m2.doflocs), float), m2.t)


def _solve(mesh, E: float, nu: float, fixed: list, loads: list) -> tuple[np.ndarray, object, float]:
    """Linear elasticity on ``mesh`` (ElementHex2): ``fixed`` = [(component, predicate(x))] zero displacements,
    ``loads`` = [(predicate(x) on facets, traction(x, n) -> (3, ...) MPa)]; returns (u (3, N), basis, seconds)."""
    from skfem import Basis, ElementHex2, FacetBasis, LinearForm, asm, condense, solve

    t0 = time.perf_counter()
    basis = Basis(mesh, ElementHex2(), intorder=4)
    n = basis.N
    K = elasticity_matrix(basis, *_lame(E, nu))
    f = np.zeros(3 * n)
    for where, traction in loads:
        facets = mesh.facets_satisfying(where, boundaries_only=True)
        if not len(facets):
            raise RuntimeError("a load selects no facets")
        fb = FacetBasis(mesh, ElementHex2(), facets=facets, intorder=4)
        for c in range(3):
            @LinearForm
            def form(v, w, c=c):
                return traction(w.x, w.n)[c] * v
            f[c * n:(c + 1) * n] += asm(form, fb)
    D = np.unique(np.concatenate([c * n + basis.get_dofs(where).all() for c, where in fixed]))
    u = solve(*condense(K, f, D=D))
    return u.reshape(3, n), basis, time.perf_counter() - t0


def _hex27(mesh, basis) -> tuple[np.ndarray, np.ndarray]:
    """Node coordinates and VTK ``hexahedron27`` connectivity of a scikit-fem ``MeshHex2`` / ``ElementHex2`` basis,
    local nodes matched by their reference coordinates (scikit-fem orders them otherwise)."""
    ref_sk = np.asarray(basis.elem.doflocs, float)
    ref_vtk = REFERENCE_ELEMENTS["hexahedron27"].nodes
    perm = [int(np.argmin(np.linalg.norm(ref_sk - r, axis=1))) for r in ref_vtk]
    if sorted(perm) != list(range(27)):
        raise RuntimeError("scikit-fem's hexahedron dof locations do not match VTK's 27 nodes")
    return basis.doflocs.T.copy(), basis.element_dofs[perm].T.copy()


def _mirror(points, cells, U, axes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model mirrored across the coordinate planes ``x_a = 0`` for each ``a`` in ``axes`` (nodes on a plane
    shared), displacements (K, P, 3) mirrored with it; reflected cells renumbered to keep a positive Jacobian."""
    ref = REFERENCE_ELEMENTS["hexahedron27"].nodes
    # reference reflection zeta -> 1 - zeta: any one restores the orientation a mirror reverses
    flip = [int(np.argmin(np.linalg.norm(ref - (r * [1, 1, -1] + [0, 0, 1]), axis=1))) for r in ref]
    P, C, V = np.asarray(points, float), np.asarray(cells), np.asarray(U, float)
    P = np.where(np.abs(P) < 1e-9 * (1 + np.abs(P).max()), 0.0, P)
    for a in axes:
        S = np.ones(3)
        S[a] = -1.0
        P2, V2, C2 = P * S, V * S, (C + len(P))[:, flip]
        P, V, C = np.concatenate([P, P2]), np.concatenate([V, V2], axis=1), np.concatenate([C, C2])
        key = np.round(P, 9)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        order = np.argsort(first)
        remap = np.empty_like(order)
        remap[order] = np.arange(len(order))
        P, V, C = P[first[order]], V[:, first[order]], remap[inverse][C]
    return P, C, V


def _quarter_in_tension(mesh, E_mpa: float, nu: float, thickness_mm: float, end_x_mm: float, stress_mpa):
    """A quarter (x, y >= 0) of a flat specimen pulled along x by 1 MPa on its x = end face, symmetric about the
    planes x = 0, y = 0 and its mid-thickness; scaled to each step's stress and mirrored whole.
    Returns (points, hexahedron27 cells, displacements (K, P, 3), solve seconds)."""
    tol = 1e-6
    u, basis, seconds = _solve(mesh, E_mpa, nu,
                               fixed=[(0, lambda x: np.abs(x[0]) < tol), (1, lambda x: np.abs(x[1]) < tol),
                                      (2, lambda x: np.abs(x[2] - thickness_mm / 2) < tol)],
                               loads=[(lambda x: np.abs(x[0] - end_x_mm) < tol,
                                       lambda x, n: np.array([np.ones_like(x[0]), 0 * x[0], 0 * x[0]]))])
    P, C = _hex27(mesh, basis)
    U = np.stack([u.T * s for s in stress_mpa])
    P, C, U = _mirror(P, C, U, (0, 1))
    return P, C, U, seconds


# ------------------------------------------------------------------------------------------------------------
def plate_with_hole(length_mm: float = 120.0, width_mm: float = 60.0, thickness_mm: float = 3.0,
                    hole_radius_mm: float = 6.0, stress_mpa=(0.0, 40.0, 80.0, 120.0), E_mpa: float = 70_000.0,
                    nu: float = 0.33, n_around: int = 12, n_radial: int = 10) -> FEResult:
    """A ``length x width x thickness`` plate (x, y, z), a central hole, remote stress along x (MPa per step).

    Quarter model on an O-grid: the parameter ``s`` runs along the quarter rectangle's outer edges (x = l/2, then
    y = w/2) and the hole's arc at the same time, ``rho`` from the hole to the edge (graded towards the hole).
    The check (``tests/test_fe_catalog.py``): the strain concentration at the hole's side, averaged through the
    thickness, against Howland's for a hole in a long strip."""
    l, w, T, a = 0.5 * length_mm, 0.5 * width_mm, thickness_mm, hole_radius_mm

    def mapping(q):
        rho, s, z = q
        theta = 0.25 * np.pi * s                                     # 0 .. pi/2 over s in [0, 2]
        hole = np.array([a * np.cos(theta), a * np.sin(theta)])
        edge = np.where(s <= 1, np.array([np.full_like(s, l), w * s]), np.array([l * (2 - s), np.full_like(s, w)]))
        g = rho ** 1.6
        xy = (1 - g) * hole + g * edge
        return np.array([xy[0], xy[1], z])

    mesh = _curved_mesh(np.linspace(0, 1, n_radial + 1), np.linspace(0, 2, n_around + 1), [0.0, T / 2, T], mapping)
    P, C, U, seconds = _quarter_in_tension(mesh, E_mpa, nu, T, l, stress_mpa)
    return FEResult("plate_with_hole", P, C, U, np.asarray(stress_mpa, float), "MPa remote stress",
                    {"length_mm": length_mm, "width_mm": width_mm, "thickness_mm": T, "hole_radius_mm": a,
                     "E_mpa": E_mpa, "nu": nu, "elements": int(len(C)), "solve_s": round(seconds, 2),
                     "about": "remote tension along x on the x = +-length/2 faces; quarter model, mirrored"})


def notched_coupon(length_mm: float = 80.0, width_mm: float = 30.0, thickness_mm: float = 3.0,
                   notch_radius_mm: float = 5.0, stress_mpa=(0.0, 40.0, 80.0, 120.0), E_mpa: float = 70_000.0,
                   nu: float = 0.33, n_x: int = 16, n_y: int = 8) -> FEResult:
    """A ``length x width x thickness`` coupon with two semicircular notches (radius r) at x = 0 on the y = +-width/2
    edges, remote stress along x. Quarter model (x >= 0, y >= 0) on one block: a Coons patch whose top side runs
    along the notch arc, then the straight edge."""
    L, W, T, r = 0.5 * length_mm, 0.5 * width_mm, thickness_mm, notch_radius_mm
    arc_len, straight = 0.5 * np.pi * r, L - r
    frac = arc_len / (arc_len + straight)

    def top(s):                    # s in [0, 1]: from (0, W - r) round the notch to (r, W), then to (L, W)
        s = np.asarray(s, float)
        phi = np.clip(s / frac, 0, 1) * 0.5 * np.pi
        on_arc = np.array([r * np.sin(phi), W - r * np.cos(phi)])
        t = np.clip((s - frac) / (1 - frac), 0, 1)
        on_edge = np.array([r + t * straight, np.full_like(t, W)])
        return np.where(s <= frac, on_arc, on_edge)

    def mapping(q):
        s, t, z = q
        bottom = np.array([s * L, 0 * s])
        tp = top(s)
        left = np.array([0 * t, t * (W - r)])
        right = np.array([np.full_like(t, L), t * W])
        c00, c10, c01, c11 = np.array([0.0, 0.0]), np.array([L, 0.0]), np.array([0.0, W - r]), np.array([L, W])
        xy = ((1 - t) * bottom + t * tp + (1 - s) * left + s * right
              - ((1 - s) * (1 - t))[None] * c00[:, None] - (s * (1 - t))[None] * c10[:, None]
              - ((1 - s) * t)[None] * c01[:, None] - (s * t)[None] * c11[:, None])
        return np.array([xy[0], xy[1], z])

    # cluster the s parameter round the notch (half the elements on its arc and the first stretch of edge)
    s_nodes = np.concatenate([np.linspace(0, frac, n_x // 2 + 1), np.linspace(frac, 1, n_x - n_x // 2 + 1)[1:]])
    mesh = _curved_mesh(s_nodes, np.linspace(0, 1, n_y + 1), [0.0, T / 2, T], mapping)
    P, C, U, seconds = _quarter_in_tension(mesh, E_mpa, nu, T, L, stress_mpa)
    return FEResult("notched_coupon", P, C, U, np.asarray(stress_mpa, float), "MPa remote stress",
                    {"length_mm": length_mm, "width_mm": width_mm, "thickness_mm": T, "notch_radius_mm": r,
                     "E_mpa": E_mpa, "nu": nu, "elements": int(len(C)), "solve_s": round(seconds, 2),
                     "about": "remote tension along x on the x = +-length/2 faces; quarter model, mirrored"})


def pressurised_cylinder(outer_radius_mm: float = 57.0, wall_mm: float = 3.0, length_mm: float = 80.0,
                         pressure_mpa=(0.0, 2.0, 4.0, 6.0), E_mpa: float = 70_000.0, nu: float = 0.33,
                         n_around: int = 12, n_axial: int = 8) -> FEResult:
    """A tube (axis along y, open ends) under internal pressure (MPa per step); its front line at z = 0 faces -z.

    Eighth model (the quarter of the ring in front of the axis, the half length y >= 0: symmetry planes x = 0,
    y = 0 and the plane z = R through the axis), mirrored. The check: Lame's thick-walled cylinder with free ends,
    ``u_r(b) = 2 p a^2 b / (E (b^2 - a^2))`` at the outer radius b."""
    b, a, Lh = outer_radius_mm, outer_radius_mm - wall_mm, 0.5 * length_mm

    def mapping(q):
        r, theta, y = q
        return np.array([r * np.sin(theta), y, b - r * np.cos(theta)])   # axis at z = b: front line at z = 0

    mesh = _curved_mesh([a, a + wall_mm / 2, b], np.linspace(0, 0.5 * np.pi, n_around + 1),
                        np.linspace(0, Lh, n_axial + 1), mapping)
    tol = 1e-6

    def inner(x):                      # facet centres lie on the chords: a tolerance, and not on a plane of symmetry
        return (np.abs(np.hypot(x[0], x[2] - b) - a) < 0.25 * wall_mm) & (np.abs(x[0]) > tol) \
            & (np.abs(x[2] - b) > tol) & (np.abs(x[1]) > tol) & (np.abs(x[1] - Lh) > tol)

    def push(x, n):                      # internal pressure of 1 MPa: along -n (n: out of the material)
        return np.array([-n[0], -n[1], -n[2]])

    u, basis, seconds = _solve(mesh, E_mpa, nu,
                               fixed=[(0, lambda x: np.abs(x[0]) < tol), (1, lambda x: np.abs(x[1]) < tol),
                                      (2, lambda x: np.abs(x[2] - b) < tol)],
                               loads=[(inner, push)])
    P, C = _hex27(mesh, basis)
    U = np.stack([u.T * p for p in pressure_mpa])
    P = P - [0.0, 0.0, b]                 # mirror about the planes through the axis
    P, C, U = _mirror(P, C, U, (0, 1, 2))
    P = P + [0.0, 0.0, b]
    return FEResult("pressurised_cylinder", P, C, U, np.asarray(pressure_mpa, float), "MPa internal pressure",
                    {"outer_radius_mm": b, "inner_radius_mm": a, "length_mm": length_mm, "E_mpa": E_mpa, "nu": nu,
                     "elements": int(len(C)), "solve_s": round(seconds, 2),
                     "lame_outer_radial_mm_per_mpa": float(2 * a * a * b / (E_mpa * (b * b - a * a))),
                     "about": "internal pressure, open ends; eighth model, mirrored"})


def beam(loads_N=(20.0, 600.0, 1200.0, 1800.0)) -> FEResult:
    """The three-point bending beam (:func:`scenes.deformation.beam_bending.solve_three_point_bending`), 120 x 30 x 10 mm."""
    from scenes.deformation.beam_bending import ThreePointBending, solve_three_point_bending

    sol = solve_three_point_bending(ThreePointBending())
    m = sol.to_meshio(1.0)
    U1 = np.asarray(m.point_data["displacement"], float)
    return FEResult("beam", np.asarray(m.points, float), np.asarray(m.cells[0].data), np.stack([U1 * L for L in loads_N]),
                    np.asarray(loads_N, float), "N load", {"elements": int(len(m.cells[0].data)),
                                                           "solve_s": round(sol.solve_time_s, 2),
                                                           "about": "three-point bending; the built-in beam's FE"})


CATALOG = {"plate_with_hole": plate_with_hole, "notched_coupon": notched_coupon,
           "pressurised_cylinder": pressurised_cylinder, "beam": beam}


def write_pvd(result: FEResult, folder) -> Path:
    """``<folder>/<name>.pvd`` and one ``<name>_KK.vtu`` per step (atomic each; the collection last)."""
    import meshio

    from labio.atomic import atomic_path, atomic_write_text

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for k, (t, U) in enumerate(zip(result.times, result.displacements_mm)):
        name = f"{result.name}_{k:02d}.vtu"
        with atomic_path(folder / name) as tmp:
            meshio.write(tmp, meshio.Mesh(result.points_mm, [("hexahedron27", result.cells)],
                                          point_data={"displacement": U}), file_format="vtu")
        entries.append(f'    <DataSet timestep="{float(t):.9g}" part="0" file="{name}"/>')
    xml = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
           + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    return atomic_write_text(folder / f"{result.name}.pvd", xml)
