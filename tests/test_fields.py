"""Displacement fields (scenes/deformation/beam_bending.py): interface, the three-point-bending FE truth, user FE meshes."""
from __future__ import annotations

import time

import meshio
import numpy as np
import pytest

from scenes.deformation.displacement_field import DifferenceField, RigidMotionField, ScaledField
from fe_reference import FEMeshField, check_covers_face
from scenes.deformation.beam_bending import (ThreePointBending, beam_theory_bending_moment_Nmm,
                                             beam_theory_outer_fibre_strain, fe_midspan_deflection_mm,
                                             section_resultants, solve_three_point_bending, three_point_bending_field,
                                             three_point_bending_report, timoshenko_midspan_deflection_mm,
                                             timoshenko_shear_coefficient)

L, H, T = 120.0, 30.0, 10.0


def _rotation(rx, ry, rz):
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _in_beam(rng, n, margin=0.0):
    lo = np.array([-L / 2, -H / 2, 0.0]) + margin
    hi = np.array([L / 2, H / 2, T]) - margin
    return rng.uniform(lo, hi, (n, 3))


@pytest.fixture(scope="module")
def beam():
    """The default FE solution (1 N), the one experiments use."""
    return solve_three_point_bending()


@pytest.fixture(scope="module")
def beam_coarse():
    return solve_three_point_bending(element_mm=5.0)


# ------------------------------------------------------------------------------------------------------------
# The interface
def test_rigid_motion_field_is_exact_and_strain_free(rng):
    R = _rotation(0.3, -0.2, 0.5)
    t = np.array([1.0, -2.0, 0.5])
    c = np.array([10.0, 3.0, 5.0])
    f = RigidMotionField(R, t, c)
    X = _in_beam(rng, 50)
    np.testing.assert_allclose(X + f(X), (X - c) @ R.T + c + t, atol=1e-12)
    np.testing.assert_allclose(f.displacement_mm(X), f(X))
    np.testing.assert_allclose(f.gradient(X), np.broadcast_to(R - np.eye(3), (50, 3, 3)), atol=1e-15)
    # A finite rotation has zero Green-Lagrange strain (the linear strain would not vanish).
    np.testing.assert_allclose(f.green_lagrange(X), 0.0, atol=1e-15)
    with pytest.raises(ValueError, match="proper rotation"):
        RigidMotionField(np.diag([1.0, 1.0, -1.0]), t)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        f(np.zeros((4, 2)))


def test_fields_are_callables_for_bending_specimen_surfaces(beam_coarse):
    from scenes.specimens.beam import BendingSpecimen

    spec = BendingSpecimen(texel_mm=0.5, speckle_mm=1.0, grid_mm=10.0)
    tex = np.zeros(spec.texture_shape, dtype=np.float32)
    R, t = np.eye(3), np.array([0.0, 0.0, 300.0])
    field = ScaledField(beam_coarse, 5000.0)
    rigid = spec.surfaces(R, t, texture=tex)
    bent = spec.surfaces(R, t, texture=tex, displacement_mm=field)
    for a, b in zip(rigid, bent):
        X = a.vertices_mm - t
        np.testing.assert_allclose(b.vertices_mm - t, X + field(X), atol=1e-12)
    assert np.max(np.abs(bent[0].vertices_mm - rigid[0].vertices_mm)) > 0.05     # 5 kN bends it ~0.08 mm


def test_scaled_and_difference_fields(rng):
    R = _rotation(0.01, 0.02, -0.03)
    a = RigidMotionField(R, [0.1, 0.2, 0.3])
    b = RigidMotionField(np.eye(3), [0.05, 0.0, -0.1])
    X = _in_beam(rng, 20)
    s = ScaledField(a, 2.5)
    np.testing.assert_allclose(s(X), 2.5 * a(X))
    np.testing.assert_allclose(s.gradient(X), 2.5 * a.gradient(X))
    d = DifferenceField(a, b)
    np.testing.assert_allclose(d(X), a(X) - b(X))
    np.testing.assert_allclose(d.gradient(X), a.gradient(X) - b.gradient(X))
    H = d.gradient(X)
    np.testing.assert_allclose(d.green_lagrange(X), 0.5 * (H + H.transpose(0, 2, 1) + H.transpose(0, 2, 1) @ H),
                               rtol=1e-12, atol=1e-15)
    assert d.contains(X).all()


# ------------------------------------------------------------------------------------------------------------
# Three-point bending FE: the model is what it says
def test_fe_stiffness_equals_scikit_fem_linear_elasticity():
    from skfem import Basis, ElementHex2, ElementVector, MeshHex, asm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    from scenes.deformation.beam_bending import _elasticity_matrix

    m = MeshHex.init_tensor(np.array([0.0, 1.0, 2.5]), np.array([0.0, 2.0]), np.array([0.0, 0.7]))
    lam, mu = lame_parameters(70_000.0, 0.33)
    vb = Basis(m, ElementVector(ElementHex2()), intorder=4)
    K = asm(linear_elasticity(lam, mu), vb)
    perm = np.concatenate(vb.split_indices())         # interleaved vector DOFs -> [u_x | u_y | u_z]
    sb = Basis(m, ElementHex2(), intorder=4)
    assert np.allclose(vb.doflocs[:, vb.split_indices()[0]], sb.doflocs)
    Kb = _elasticity_matrix(sb, lam, mu)
    assert abs(K[perm][:, perm] - Kb).max() <= 1e-12 * abs(K).max()


def test_fe_evaluation_equals_scikit_fem_interpolation(beam_coarse, rng):
    """The fast structured evaluation is ElementHex2's own interpolation (scikit-fem's probes)."""
    from skfem import Basis, ElementHex2, MeshHex

    s = beam_coarse
    m = MeshHex.init_tensor(s.x_nodes_mm, s.y_nodes_mm, s.z_nodes_mm)
    basis = Basis(m, ElementHex2(), intorder=4)
    gx, gy, gz, U = s.full_grid()
    # Nodal vector from the quarter part of the full grid (x >= 0, z <= T/2).
    ix = [np.abs(g[:, None] - c[None, :]).argmin(axis=0) for g, c in zip((gx, gy, gz), basis.doflocs)]
    u = U[ix[0], ix[1], ix[2]]                               # (N, 3)
    Xq = rng.uniform([0.0, -H / 2, 0.0], [L / 2, H / 2, T / 2], (300, 3))
    P = basis.probes(Xq.T)
    ref = np.stack([P @ u[:, i] for i in range(3)], axis=1)
    np.testing.assert_allclose(s(Xq), ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_fe_equilibrium_reactions_and_section_resultants(beam):
    """Supports carry the whole load; FE stresses give the statically required section forces."""
    p = beam.params
    assert beam.support_force_N == pytest.approx(1.0, rel=1e-12)
    assert abs(beam.ground_reaction_N) < 1e-9          # nothing but the smeared contacts carries load
    load = 1000.0
    field = three_point_bending_field(load)
    for x in (-40.0, -25.0, -10.0, 10.0, 25.0, 40.0):
        r = section_resultants(field, x, p)
        assert r["moment_Nmm"] == pytest.approx(float(beam_theory_bending_moment_Nmm(x, load, p)), rel=1e-3)
        assert r["shear_N"] == pytest.approx(-np.sign(x) * load / 2, rel=1e-2)
        assert abs(r["axial_N"]) < 1e-3 * load


def test_fe_symmetry(beam, rng):
    X = _in_beam(rng, 200)
    Xm = X * np.array([-1.0, 1.0, 1.0])
    u, um = beam(X), beam(Xm)
    np.testing.assert_allclose(um[:, 0], -u[:, 0], atol=1e-20)
    np.testing.assert_allclose(um[:, 1:], u[:, 1:], atol=1e-20)
    Xz = X * np.array([1.0, 1.0, -1.0]) + np.array([0.0, 0.0, T])
    uz = beam(Xz)
    np.testing.assert_allclose(uz[:, 2], -u[:, 2], atol=1e-20)
    np.testing.assert_allclose(uz[:, :2], u[:, :2], atol=1e-20)
    on_plane = np.column_stack([np.zeros(20), rng.uniform(-H / 2, H / 2, 20), rng.uniform(0, T, 20)])
    assert np.all(beam(on_plane)[:, 0] == 0.0)
    assert np.all(beam(on_plane)[:, 1] > 0)             # the whole mid-section moves down (+y)


def test_fe_linear_in_load(beam, rng):
    X = _in_beam(rng, 100)
    f1, f2, f3 = three_point_bending_field(700.0), three_point_bending_field(1300.0), three_point_bending_field(2000.0)
    assert f1.base is f2.base is beam                     # one cached 1 N solution
    np.testing.assert_allclose(f1(X) + f2(X), f3(X), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(f3.gradient(X), 2000.0 * beam.gradient(X), rtol=1e-12)
    d = fe_midspan_deflection_mm(f3, beam.params)["midspan_deflection_mm"]
    assert d == pytest.approx(2000.0 * fe_midspan_deflection_mm(beam, beam.params)["midspan_deflection_mm"], rel=1e-12)


def test_fe_front_face_top_compressed_bottom_stretched(beam):
    for x in (0.0, -5.0, 5.0):
        H_top, H_bot = beam.gradient(np.array([[x, -H / 2, 0.0], [x, H / 2, 0.0]]))
        assert H_top[0, 0] < 0 < H_bot[0, 0]
    E = three_point_bending_field(1000.0).green_lagrange(np.array([[0.0, -H / 2, 0.0], [0.0, H / 2, 0.0]]))
    assert E[0, 0, 0] < 0 < E[1, 0, 0]


def test_fe_gradient_matches_finite_difference(beam, rng):
    """Points inside elements: a central difference of a piecewise quadratic is exact up to rounding."""
    s = beam
    cells = []
    for nodes in (s.x_nodes_mm, s.y_nodes_mm, s.z_nodes_mm):
        e = rng.integers(0, len(nodes) - 1, 100)
        cells.append(nodes[e] + rng.uniform(0.1, 0.9, 100) * (nodes[e + 1] - nodes[e]))
    X = np.stack(cells, axis=1)
    X[:50, 0] *= -1                                    # the mirrored half too
    X[:25, 2] = T - X[:25, 2]
    H_exact = s.gradient(X)
    h = 1e-3
    H_fd = np.empty_like(H_exact)
    for j in range(3):
        d = np.zeros(3)
        d[j] = h
        H_fd[:, :, j] = (s(X + d) - s(X - d)) / (2 * h)
    scale = np.abs(H_exact).max()
    assert np.abs(H_fd - H_exact).max() < 1e-8 * scale


def test_fe_outside_points_raise(beam):
    X = np.array([[0.0, 0.0, 5.0], [61.0, 0.0, 5.0], [0.0, 0.0, -0.5]])
    with pytest.raises(ValueError, match=r"2 of 3 points lie outside .*x in \[0, 61\] mm.*z in \[-0.5, 5\] mm"):
        beam(X)
    assert list(beam.contains(X)) == [True, False, False]
    # Surface points a rounding error outside are accepted.
    beam(np.array([[60.0 + 1e-12, -15.0 - 1e-12, -1e-12]]))


# ------------------------------------------------------------------------------------------------------------
# Three-point bending FE against beam theory, and against an independent 2-D plane-stress FE
def _plane_stress_fe(p: ThreePointBending, element_mm: float, strain_x_mm: float) -> dict:
    """An independent 2-D plane-stress FE of the beam: quadratic triangles, full 120 x 30 domain, no symmetry.

    Same contact model as :func:`solve_three_point_bending` (nose pressure over ``|x| <= w_nose/2`` on the top
    edge ``y = -H/2``, roller pressures over ``w_sup`` strips at ``x = +-S/2`` on the bottom edge ``y = +H/2``,
    loads per unit thickness P/T with P = 1 N, y down), but its own mesh, element and assembly (scikit-fem's
    ``linear_elasticity`` with the plane-stress Lame parameter ``lambda* = 2 lambda mu / (lambda + 2 mu)``).
    Rigid modes: u_x, u_y fixed at the left support point and u_y at the right one (the loads balance, so the
    reactions are ~0 and the supports are not clamped), then the rigid motion making the mean u_y over each
    support strip zero is subtracted. Returns the mid-span deflection (neutral axis at x = 0 minus the mean of
    x = +-S/2, as :func:`fe_midspan_deflection_mm`), ``du_x/dx`` on the top / bottom edges at
    ``x = +-strain_x_mm`` (vertices there: the mean of the two adjacent elements' values), and the reactions.
    """
    import scipy.sparse.linalg as spla
    from skfem import Basis, ElementTriP2, ElementVector, FacetBasis, LinearForm, MeshTri, asm, condense, solve
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    Lb, Hb, Tb, S, wn, ws = p.length_mm, p.height_mm, p.thickness_mm, p.span_mm, p.nose_width_mm, p.support_width_mm

    def axis(breaks):
        return np.unique(np.concatenate([np.linspace(a, b, int(np.ceil((b - a) / element_mm - 1e-9)) + 1)
                                         for a, b in zip(breaks[:-1], breaks[1:])]))

    mesh = MeshTri.init_tensor(axis([-Lb / 2, -S / 2 - ws / 2, -S / 2 + ws / 2, -wn / 2, wn / 2, S / 2 - ws / 2,
                                     S / 2 + ws / 2, Lb / 2]), axis([-Hb / 2, Hb / 2]))
    lam, mu = lame_parameters(p.youngs_modulus_mpa, p.poisson_ratio)
    element = ElementVector(ElementTriP2())
    basis = Basis(mesh, element, intorder=4)
    K = asm(linear_elasticity(2 * lam * mu / (lam + 2 * mu), mu), basis)

    @LinearForm
    def v_y(v, w):
        return v[1]

    tol = 1e-9 * Lb

    def strip(y, centre, width):          # integral of v_y over an edge strip
        facets = mesh.facets_satisfying(lambda x: (np.abs(x[1] - y) < tol) & (np.abs(x[0] - centre) < width / 2))
        return asm(v_y, FacetBasis(mesh, element, facets=facets, intorder=4))

    nose, left, right = strip(-Hb / 2, 0.0, wn), strip(Hb / 2, -S / 2, ws), strip(Hb / 2, S / 2, ws)
    f = (nose / wn - 0.5 * (left + right) / ws) / Tb                 # +y (down) on top, up on the rollers
    corner = [int(np.argmin(np.hypot(mesh.p[0] - x, mesh.p[1] - Hb / 2))) for x in (-S / 2, S / 2)]
    D = np.array([basis.nodal_dofs[0, corner[0]], basis.nodal_dofs[1, corner[0]], basis.nodal_dofs[1, corner[1]]])

    def symmetric_lu(A, b, **_):          # SuperLU in symmetric mode: ~2x faster than the default here
        return spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                         options={"SymmetricMode": True}).solve(b)

    u = solve(*condense(K, f, D=D), solver=symmetric_lu)
    reactions = (K @ u - f)[D]
    m_left, m_right = left @ u / ws, right @ u / ws                   # mean u_y over each strip
    rot = (m_right - m_left) / S                                      # rigid u = (-rot y, mean + rot x)
    ix, iy = basis.split_indices()
    u[iy] -= 0.5 * (m_left + m_right) + rot * basis.doflocs[0, iy]
    u[ix] += rot * basis.doflocs[1, ix]
    (ux, bx), (uy, by) = basis.split(u)

    def dux_dx(points):
        x = np.asarray(points, float).T
        cells = bx.mesh.element_finder(mapping=bx.mapping)(*x)
        ref = bx.mapping.invF(x[:, :, None], tind=cells)
        return sum(ux[bx.element_dofs[k, cells]] * bx.elem.gbasis(bx.mapping, ref, k, tind=cells)[0].grad[0][:, 0]
                   for k in range(bx.Nbfun))

    uy0, uyl, uyr = by.probes(np.array([[0.0, -S / 2, S / 2], [0.0, 0.0, 0.0]])) @ uy
    strains = {}
    for x in (-strain_x_mm, strain_x_mm):
        for y, face in ((-Hb / 2, "top"), (Hb / 2, "bottom")):
            strains[x, face] = float(np.mean(dux_dx([[x - 1e-6, y], [x + 1e-6, y]])))
    return {"midspan_deflection_mm": uy0 - 0.5 * (uyl + uyr), "strain": strains, "reactions_N": reactions}


_PLANE_STRESS_TOL = 0.005       # 3-D against the 2-D reference, relative (see the test's docstring)


@pytest.fixture(scope="module")
def plane_stress():
    """The 2-D plane-stress reference of the default beam, 1 mm and 0.5 mm triangles (~0.6 s + ~3 s)."""
    return {h: _plane_stress_fe(ThreePointBending(), h, 25.0) for h in (1.0, 0.5)}


def test_short_beam_3d_fe_agrees_with_an_independent_plane_stress_fe(beam, plane_stress):
    """The short beam's departures from beam theory belong to the elasticity problem, not to the 3-D model.

    On this beam (span/height 3.3) the 3-D FE is -4.36 % off Timoshenko in mid-span deflection, and its front-face
    outer-fibre strains at x = +-25 mm are -4.13 % (top) / +3.93 % (bottom) off M c / (E I). The issue's goals
    (2 % and 3 % against beam theory) are not asserted: the independent 2-D plane-stress FE (quadratic
    triangles, full domain, same contact model) misses them the same way, -4.35 %, -4.04 %, +3.91 %. 3-D against
    2-D: deflection -0.01 %, top strain -0.09 %, bottom +0.02 %. Tolerance 0.5 %: plane stress is not exact
    for a 10 mm-thick beam (in the 3-D the front-face and mid-thickness strains differ by 0.1 %), and x = +-25 mm
    is a node of the 3-D's 2.5 mm mesh, where its gradient is one-sided (the two sides differ by 0.05 %); 0.5 %
    is still an eighth of the 4 % departures being explained.
    """
    p = beam.params
    ref = plane_stress[1.0]
    rows = [("mid-span deflection", fe_midspan_deflection_mm(beam, p)["midspan_deflection_mm"],
             ref["midspan_deflection_mm"], timoshenko_midspan_deflection_mm(1.0, p), 0.02)]
    for x in (-25.0, 25.0):
        th = float(beam_theory_outer_fibre_strain(x, 1.0, p))
        top, bot = beam.gradient(np.array([[x, -H / 2, 0.0], [x, H / 2, 0.0]]))[:, 0, 0]
        rows += [(f"top strain x = {x:+g}", top, ref["strain"][x, "top"], -th, 0.03),
                 (f"bottom strain x = {x:+g}", bot, ref["strain"][x, "bottom"], th, 0.03)]
    for name, fe3, fe2, theory, goal in rows:
        print(f"{name}: 3-D {100 * (fe3 / theory - 1):+.2f} %, 2-D {100 * (fe2 / theory - 1):+.2f} % off beam "
              f"theory; 3-D vs 2-D {100 * (fe3 / fe2 - 1):+.3f} %")
        assert fe3 == pytest.approx(fe2, rel=_PLANE_STRESS_TOL)
        # Both depart from beam theory the same way, and the reference by more than the goal.
        assert np.sign(fe3 / theory - 1) == np.sign(fe2 / theory - 1)
        assert abs(fe2 / theory - 1) > goal


def test_plane_stress_reference_is_mesh_converged_and_meets_beam_theory_on_a_slender_beam(plane_stress):
    """Halving the 2-D elements (1 -> 0.5 mm) moves its figures by < 0.01 %, far below the 0.5 % tolerance;
    the contact loads balance (the three held DOFs carry ~1e-12 N); on a span/height-20 beam the same helper
    meets Timoshenko to 0.07 % and M c / (E I) to 1e-8."""
    coarse, fine = plane_stress[1.0], plane_stress[0.5]
    assert fine["midspan_deflection_mm"] == pytest.approx(coarse["midspan_deflection_mm"], rel=_PLANE_STRESS_TOL / 10)
    for key, e in fine["strain"].items():
        assert e == pytest.approx(coarse["strain"][key], rel=_PLANE_STRESS_TOL / 10)
    assert max(np.abs(r["reactions_N"]).max() for r in (coarse, fine)) < 1e-9
    p = ThreePointBending(length_mm=620.0, span_mm=600.0)
    s = _plane_stress_fe(p, 2.5, p.span_mm / 4)
    assert s["midspan_deflection_mm"] == pytest.approx(timoshenko_midspan_deflection_mm(1.0, p), rel=0.002)
    th = float(beam_theory_outer_fibre_strain(p.span_mm / 4, 1.0, p))
    for (x, face), e in s["strain"].items():
        assert e == pytest.approx(th if face == "bottom" else -th, rel=0.002)


def test_fe_slender_beam_matches_beam_theory():
    """Where beam theory holds (span/height 20) the same model meets it: the short-beam misses are physics."""
    p = ThreePointBending(length_mm=620.0, span_mm=600.0, element_mm=5.0)
    s = solve_three_point_bending(p)
    d = fe_midspan_deflection_mm(s, p)["midspan_deflection_mm"]
    assert d == pytest.approx(timoshenko_midspan_deflection_mm(1.0, p), rel=0.002)
    x = p.span_mm / 4
    th = float(beam_theory_outer_fibre_strain(x, 1.0, p))
    top, bot = s.gradient(np.array([[x, -H / 2, 0.0], [x, H / 2, 0.0]]))[:, 0, 0]
    assert top == pytest.approx(-th, rel=0.002)
    assert bot == pytest.approx(th, rel=0.002)


def test_beam_theory_formulas():
    p = ThreePointBending()
    I = 10 * 30 ** 3 / 12
    assert timoshenko_midspan_deflection_mm(1.0, p, shear=False) == pytest.approx(100 ** 3 / (48 * 70_000 * I))
    kappa = 10 * 1.33 / (12 + 11 * 0.33)
    assert timoshenko_shear_coefficient(0.33) == pytest.approx(kappa)
    G = 70_000 / 2.66
    assert timoshenko_midspan_deflection_mm(1.0, p) == pytest.approx(100 ** 3 / (48 * 70_000 * I)
                                                                     + 100 / (4 * kappa * G * 300))
    assert timoshenko_midspan_deflection_mm(2.0, span_mm=80.0) == pytest.approx(
        2 * timoshenko_midspan_deflection_mm(1.0, ThreePointBending(span_mm=80.0)))
    np.testing.assert_allclose(beam_theory_outer_fibre_strain([-25.0, 25.0, 55.0], 1.0, p),
                               [12.5 * 15 / (70_000 * I)] * 2 + [0.0])


def test_fe_mesh_refinement_5_to_2p5_mm(beam, beam_coarse):
    p = beam.params
    d_fine = fe_midspan_deflection_mm(beam, p)["midspan_deflection_mm"]
    d_coarse = fe_midspan_deflection_mm(beam_coarse, p)["midspan_deflection_mm"]
    assert abs(d_fine / d_coarse - 1) < 0.005


@pytest.mark.slow
def test_fe_mesh_refinement_2p5_to_1p25_mm(beam):
    """~130 000 unknowns: about 100 s with SuperLU on one core."""
    p = beam.params
    fine = solve_three_point_bending(element_mm=1.25)
    d_fine = fe_midspan_deflection_mm(fine, p)["midspan_deflection_mm"]
    d = fe_midspan_deflection_mm(beam, p)["midspan_deflection_mm"]
    assert abs(d_fine / d - 1) < 0.005


def test_fe_default_solve_and_evaluation_speed(beam, rng):
    assert beam.solve_time_s < 15.0                     # ~2 s on one core
    X = _in_beam(rng, 200_000)
    t0 = time.perf_counter()
    beam(X)
    beam.gradient(X)
    assert time.perf_counter() - t0 < 4.0                # ~0.8 s for value + gradient on one core


def test_three_point_bending_report(beam, beam_coarse):
    r = three_point_bending_report()
    assert r["params"] == ThreePointBending().to_dict()
    assert r["timoshenko"]["total_mm"] == pytest.approx(timoshenko_midspan_deflection_mm(1.0))
    assert r["fe"]["midspan_deflection_mm"] == pytest.approx(
        fe_midspan_deflection_mm(beam, beam.params)["midspan_deflection_mm"])
    assert len(r["outer_fibre_strain"]) == 4 and all(abs(s["error_pct"]) < 10 for s in r["outer_fibre_strain"])
    assert r["refinement"]["element_mm"] == [5.0, 2.5] and abs(r["refinement"]["change_pct"]) < 0.5
    assert r["fe"]["support_force_N"] == pytest.approx(1.0)


def test_parameters_are_validated():
    with pytest.raises(ValueError, match="element_mm"):
        ThreePointBending(element_mm=0.0)
    with pytest.raises(ValueError, match="support strips"):
        ThreePointBending(span_mm=119.0)
    with pytest.raises(ValueError, match="poisson"):
        ThreePointBending(poisson_ratio=0.5)
    with pytest.raises(TypeError, match="pass either params or keyword overrides, not both"):
        three_point_bending_field(1.0, ThreePointBending(), element_mm=5.0)


# ------------------------------------------------------------------------------------------------------------
# User FE results
def _grid_nodes(n, lo, hi, rng=None, jitter=0.0):
    """Structured nodes (nx+1, ny+1, nz+1, 3); interior nodes jittered by ``jitter`` of a cell."""
    axes = [np.linspace(a, b, k + 1) for a, b, k in zip(lo, hi, n)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    if jitter:
        h = (np.asarray(hi) - np.asarray(lo)) / np.asarray(n)
        inner = (slice(1, -1),) * 3
        P[inner] += rng.uniform(-jitter, jitter, P[inner].shape) * h
    return P


def _hexes(n):
    """VTK-ordered hexahedra (E, 8) on a structured (nx+1, ny+1, nz+1) node grid."""
    nx, ny, nz = n
    idx = np.arange((nx + 1) * (ny + 1) * (nz + 1)).reshape(nx + 1, ny + 1, nz + 1)
    c = [idx[i:i + nx, j:j + ny, k:k + nz].ravel() for i, j, k in
         [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]]
    return np.stack(c, axis=1)


def _tets(hexes):
    """Six conforming tetrahedra per hexahedron around its 0-6 diagonal."""
    local = [(0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6), (0, 5, 1, 6)]
    return np.concatenate([hexes[:, list(t)] for t in local])


def _tet10(points, tets):
    """Add shared straight-edge midpoints: VTK tetra10 order (edges 01, 12, 02, 03, 13, 23)."""
    edges = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]
    pairs = np.sort(np.concatenate([tets[:, [a, b]] for a, b in edges]), axis=1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    mids = 0.5 * (points[uniq[:, 0]] + points[uniq[:, 1]])
    conn = np.concatenate([tets, len(points) + inv.reshape(len(edges), len(tets)).T], axis=1)
    return np.concatenate([points, mids]), conn


def _hex27(n, lo, hi):
    """Hexahedron27 cells (VTK order) on a box: a (2n+1)-node grid, as the exporter builds it."""
    from scenes.deformation.fe_elements import REFERENCE_ELEMENTS as _REFERENCE

    P = _grid_nodes(tuple(2 * k for k in n), lo, hi).reshape(-1, 3)
    G = np.array([2 * k + 1 for k in n])
    e = np.stack(np.meshgrid(*(np.arange(k) for k in n), indexing="ij"), -1).reshape(-1, 3)
    off = np.rint(2 * _REFERENCE["hexahedron27"].nodes).astype(int)
    ijk = 2 * e[:, None, :] + off[None]
    return P, (ijk[..., 0] * G[1] + ijk[..., 1]) * G[2] + ijk[..., 2]


_BOX_LO, _BOX_HI = (-L / 2, -H / 2, 0.0), (L / 2, H / 2, T)


def _linear(rng):
    A, b = rng.normal(0, 1e-3, (3, 3)), rng.normal(0, 0.05, 3)
    return (lambda X: X @ A.T + b), (lambda X: np.broadcast_to(A, (len(X), 3, 3)))


def _quadratic(rng):
    Q = rng.normal(0, 1e-5, (3, 3, 3))
    Q = 0.5 * (Q + Q.transpose(0, 2, 1))
    lin, dlin = _linear(rng)
    return (lambda X: np.einsum("ijk,nj,nk->ni", Q, X, X) + lin(X),
            lambda X: 2 * np.einsum("ijk,nk->nij", Q, X) + dlin(X))


def _write(tmp_path, name, points, cells, point_data):
    path = tmp_path / name
    meshio.write(path, meshio.Mesh(points, cells, point_data=point_data))
    return path


def _reproduction_error(field, u, du, rng, n=300):
    """Largest |value| and |gradient| error of ``field`` against the analytic (u, du) at random interior points."""
    X = _in_beam(rng, n, margin=1e-3)
    return float(np.max(np.abs(field(X) - u(X)))), float(np.max(np.abs(field.gradient(X) - du(X))))


def test_mesh_field_tetra_reproduces_linear_field(tmp_path, rng):
    n = (8, 4, 2)
    P = _grid_nodes(n, _BOX_LO, _BOX_HI, rng, jitter=0.25).reshape(-1, 3)
    u, du = _linear(rng)
    path = _write(tmp_path, "tets.vtu", P, [("tetra", _tets(_hexes(n)))], {"displacement": u(P)})
    f = FEMeshField.from_file(path)
    assert list(f.cells) == ["tetra"]
    assert max(_reproduction_error(f, u, du, rng)) <= 1e-10
    f.check_covers_face(L, H)


def test_mesh_field_tetra10_reproduces_quadratic_field(tmp_path, rng):
    n = (6, 3, 2)
    P, conn = _tet10(_grid_nodes(n, _BOX_LO, _BOX_HI, rng, jitter=0.2).reshape(-1, 3), _tets(_hexes(n)))
    u, du = _quadratic(rng)
    path = _write(tmp_path, "tet10.vtu", P, [("tetra10", conn)], {"U": u(P), "temperature": P[:, 0]})
    assert max(_reproduction_error(FEMeshField.from_file(path), u, du, rng)) <= 1e-10


def test_mesh_field_hexahedron(tmp_path, rng):
    n = (6, 3, 2)
    # Box cells: trilinear fields exactly (x y z included).
    P = _grid_nodes(n, _BOX_LO, _BOX_HI).reshape(-1, 3)
    c = rng.normal(0, 1e-6, 3)
    u = lambda X: np.stack([c[0] * X[:, 0] * X[:, 1] * X[:, 2], c[1] * X[:, 0] * X[:, 1], c[2] * X[:, 1] * X[:, 2]], 1)
    du = lambda X: np.stack([c[0] * np.stack([X[:, 1] * X[:, 2], X[:, 0] * X[:, 2], X[:, 0] * X[:, 1]], 1),
                             c[1] * np.stack([X[:, 1], X[:, 0], 0 * X[:, 0]], 1),
                             c[2] * np.stack([0 * X[:, 0], X[:, 2], X[:, 1]], 1)], 1)
    path = _write(tmp_path, "hex.vtu", P, [("hexahedron", _hexes(n))], {"disp": u(P)})
    assert max(_reproduction_error(FEMeshField.from_file(path), u, du, rng)) <= 1e-10
    # Distorted (non-affine) cells: isoparametric, so linear fields exactly.
    P = _grid_nodes(n, _BOX_LO, _BOX_HI, rng, jitter=0.2).reshape(-1, 3)
    lu, dlu = _linear(rng)
    path = _write(tmp_path, "hex_distorted.vtu", P, [("hexahedron", _hexes(n))], {"disp": lu(P)})
    assert max(_reproduction_error(FEMeshField.from_file(path), lu, dlu, rng)) <= 1e-10


def test_mesh_field_hexahedron27_and_20_reproduce_quadratic_fields(tmp_path, rng):
    n = (4, 2, 2)
    P, conn = _hex27(n, _BOX_LO, _BOX_HI)
    u, du = _quadratic(rng)
    path = _write(tmp_path, "hex27.vtu", P, [("hexahedron27", conn)], {"displacement": u(P)})
    assert max(_reproduction_error(FEMeshField.from_file(path), u, du, rng)) <= 1e-10
    # The serendipity hexahedron20 (same corner/edge nodes) holds total degree 2.
    path = _write(tmp_path, "hex20.vtu", P, [("hexahedron20", conn[:, :20])], {"displacement": u(P)})
    assert max(_reproduction_error(FEMeshField.from_file(path), u, du, rng)) <= 1e-10


def test_mesh_field_wedge_reproduces_linear_field(tmp_path, rng):
    n = (6, 3, 2)
    P = _grid_nodes(n, _BOX_LO, _BOX_HI, rng, jitter=0.0).reshape(-1, 3)
    h = _hexes(n)
    wedges = np.concatenate([h[:, [0, 1, 3, 4, 5, 7]], h[:, [1, 2, 3, 5, 6, 7]]])   # two prisms per hex
    u, du = _linear(rng)
    path = _write(tmp_path, "wedge.vtu", P, [("wedge", wedges)], {"displacement": u(P)})
    assert max(_reproduction_error(FEMeshField.from_file(path), u, du, rng)) <= 1e-10


def test_mesh_field_node_orders_match_scikit_fem_export(rng):
    """Independent check of the VTK node orders: scikit-fem's own meshio export (skfem.io.meshio)."""
    from skfem import MeshHex1, MeshHex2, MeshTet1, MeshTet2
    from skfem.io.meshio import to_meshio

    axes = (np.linspace(-L / 2, L / 2, 4), np.linspace(-H / 2, H / 2, 3), np.linspace(0, T, 3))
    X = _in_beam(rng, 200, margin=1e-3)
    for mesh, degree in ((MeshHex1.init_tensor(*axes), 1), (MeshHex2.from_mesh(MeshHex1.init_tensor(*axes)), 2),
                         (MeshTet2.from_mesh(MeshTet1.init_tensor(*axes)), 2)):
        m = to_meshio(mesh)
        u, du = _quadratic(rng) if degree == 2 else _linear(rng)
        m.point_data = {"displacement": u(m.points)}
        f = FEMeshField.from_meshio(m)
        np.testing.assert_allclose(f(X), u(X), rtol=0, atol=1e-10)
        np.testing.assert_allclose(f.gradient(X), du(X), rtol=0, atol=1e-10)


def test_mesh_field_legacy_vtk_units_and_frame(tmp_path, rng):
    """A mesh in metres with its origin at a beam corner, as many FE models are, mapped into the specimen frame."""
    n = (6, 3, 2)
    P_mm = _grid_nodes(n, _BOX_LO, _BOX_HI, rng, jitter=0.2).reshape(-1, 3)
    u, du = _linear(rng)
    corner = np.array([-L / 2, -H / 2, 0.0])
    path = _write(tmp_path, "metres.vtk", (P_mm - corner) / 1000, [("tetra", _tets(_hexes(n)))],
                  {"displacement": u(P_mm) / 1000})
    f = FEMeshField.from_file(path, "displacement", scale_to_mm=1000.0, t_specimen_from_mesh_mm=corner)
    assert max(_reproduction_error(f, u, du, rng)) <= 1e-9


def test_mesh_field_refuses_half_face(tmp_path, rng):
    n = (4, 3, 2)
    P = _grid_nodes(n, (0.0, -H / 2, 0.0), (L / 2, H / 2, T)).reshape(-1, 3)
    path = _write(tmp_path, "half.vtu", P, [("hexahedron", _hexes(n))], {"displacement": 0 * P})
    f = FEMeshField.from_file(path)
    with pytest.raises(ValueError, match=r"half\.vtu does not cover .* 1860 of 3751 sample points \(49\.6 %\) are "
                                         r"uncovered, in the region x in \[-60, -1\] mm, y in \[-15, 15\] mm"):
        check_covers_face(f, L, H)
    with pytest.raises(ValueError, match=r"points lie outside the mesh of .*half\.vtu"):
        f(np.array([[-10.0, 0.0, 5.0]]))
    assert f.contains(np.array([[10.0, 0.0, 5.0], [-10.0, 0.0, 5.0]])).tolist() == [True, False]


def test_mesh_field_point_data_errors(tmp_path, rng):
    n = (2, 1, 1)
    P = _grid_nodes(n, _BOX_LO, _BOX_HI).reshape(-1, 3)
    cells = [("hexahedron", _hexes(n))]
    none = _write(tmp_path, "none.vtu", P, cells, {})
    with pytest.raises(ValueError, match=r"none\.vtu: nodal displacement missing.*available point data: none"):
        FEMeshField.from_file(none)
    two = _write(tmp_path, "two.vtu", P, cells, {"velocity": P * 0, "force": P * 0})
    with pytest.raises(ValueError, match=r"two\.vtu: nodal displacement ambiguous.*velocity \(12, 3\), force"):
        FEMeshField.from_file(two)
    assert FEMeshField.from_file(two, displacement_name="force").cells["hexahedron"].shape == (2, 8)
    with pytest.raises(ValueError, match=r"no point data named 'u'; available point data: velocity \(12, 3\)"):
        FEMeshField.from_file(two, displacement_name="u")
    scal = _write(tmp_path, "scal.vtu", P, cells, {"disp_x": P[:, 0], "disp_y": P[:, 1], "disp_z": P[:, 2],
                                                   "temp": P[:, 0]})
    np.testing.assert_allclose(FEMeshField.from_file(scal).nodal_displacement_mm, P)    # scalar components
    with pytest.raises(ValueError, match=r"'temp' has shape \(12,\)"):
        FEMeshField.from_file(scal, displacement_name="temp")


def test_mesh_field_not_a_mesh(tmp_path):
    bogus = tmp_path / "bogus.vtu"
    bogus.write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match=r"bogus\.vtu: not a mesh file meshio can read"):
        FEMeshField.from_file(bogus)
    txt = tmp_path / "notes.txt"
    txt.write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"notes\.txt: not a mesh file"):
        FEMeshField.from_file(txt)
    surf = _write(tmp_path, "surface.vtu", np.eye(3), [("triangle", np.array([[0, 1, 2]]))],
                  {"displacement": np.zeros((3, 3))})
    with pytest.raises(ValueError, match=r"surface\.vtu: no volume cells of a supported type.*has: triangle"):
        FEMeshField.from_file(surf)
    with pytest.raises(FileNotFoundError, match=r"missing\.vtu"):
        FEMeshField.from_file(tmp_path / "missing.vtu")


def test_builtin_solution_vtu_roundtrip(beam_coarse, tmp_path, rng):
    """The built-in FE solution exported to VTU and read back agrees with the built-in evaluation."""
    path = tmp_path / "beam.vtu"
    meshio.write(path, beam_coarse.to_meshio(load_N=1000.0))
    f = FEMeshField.from_file(path)
    assert list(f.cells) == ["hexahedron27"]
    f.check_covers_face(L, H)
    field = three_point_bending_field(1000.0, element_mm=5.0)
    X = _in_beam(rng, 2000)
    ref = field(X)
    np.testing.assert_allclose(f(X), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    Hr = field.gradient(X)
    np.testing.assert_allclose(f.gradient(X), Hr, rtol=0, atol=1e-10 * np.abs(Hr).max())


def test_mesh_field_exodus(tmp_path, rng):
    pytest.importorskip("netCDF4")
    n = (4, 2, 2)
    P = _grid_nodes(n, _BOX_LO, _BOX_HI, rng, jitter=0.2).reshape(-1, 3)
    u, du = _linear(rng)
    for name, cells in (("tetra", _tets(_hexes(n))), ("hexahedron", _hexes(n))):
        path = _write(tmp_path, f"{name}.exo", P, [(name, cells)], {"displacement": u(P)})
        assert max(_reproduction_error(FEMeshField.from_file(path), u, du, rng)) <= 1e-10
    P27, conn = _hex27((2, 1, 1), _BOX_LO, _BOX_HI)
    path = _write(tmp_path, "hex27.exo", P27, [("hexahedron27", conn)], {"displacement": 0 * P27})
    with pytest.raises(ValueError, match="Exodus"):
        FEMeshField.from_file(path)
