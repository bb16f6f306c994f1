"""Tests for measurement.strain: surface strain from point grids (Cosserat triangles and strain windows).

Every expected value is analytic (from the imposed deformation and the geometry), never the code's own output.
Conventions used below: a flat plate has plate coordinates x = j h (columns), y = i h (rows), z = 0 and is
placed in space by a rotation R_p; its frame (R_p x^, R_p y^, R_p z^) is then the module's (e1, e2, n).
"""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measurement.strain import (TRIANGLE_GAUGE_WINDOW, surface_strain, triangle_strain, triangulate_grid,
                                virtual_strain_gauge_px)

METHODS = [dict(), dict(window=5, fit="linear"), dict(window=5, fit="quadratic")]
METHOD_IDS = ["triangle", "window-linear", "window-quadratic"]


# ----------------------------------------------------------------------------------------------- geometry

def _plate(rows, cols, step, seed):
    """A flat plate grid in a seeded random orientation: (plate coords (rows, cols, 3), R_p, t_p)."""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    p = np.stack([j * step, i * step, np.zeros((rows, cols))], axis=-1)
    R_p = Rotation.random(random_state=seed).as_matrix()
    t_p = np.random.default_rng(seed).uniform(-30, 30, 3) + [0, 0, 350]
    return p, R_p, t_p


def _cylinder(rows, cols, radius, step, R0, t0):
    """Cylinder patch (axis along the rows): columns step along the arc, rows along the axis, both by ``step``.

    Returns X (rows, cols, 3) and the angle theta (rows, cols) of each point; in the local frame a point is
    (radius sin theta, z, radius cos theta), the outward radial direction (sin theta, 0, cos theta) is the
    grid-oriented normal dX/dj x dX/di and the arc tangent (cos theta, 0, -sin theta) is the column direction.
    """
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    theta = (j - (cols - 1) / 2) * step / radius
    local = np.stack([radius * np.sin(theta), i * step, radius * np.cos(theta)], axis=-1)
    return local @ R0.T + t0, theta


def _cylinder_frame(theta, R0):
    """Analytic (e1, e2, n) on the cylinder at angle theta for the reference direction R0 x^."""
    zero = np.zeros_like(theta)
    e1 = np.stack([np.cos(theta), zero, -np.sin(theta)], -1) @ R0.T
    n = np.stack([np.sin(theta), zero, np.cos(theta)], -1) @ R0.T
    e2 = np.broadcast_to(R0[:, 1], e1.shape)
    return e1, e2, n


def _strain_in_frame(F, e1, e2):
    """E_ab = (F e_a . F e_b - delta_ab) / 2 for a homogeneous 3-D F and frame vectors (..., 3)."""
    Fe1, Fe2 = e1 @ F.T, e2 @ F.T
    return (0.5 * (np.sum(Fe1 * Fe1, -1) - 1), 0.5 * (np.sum(Fe2 * Fe2, -1) - 1), 0.5 * np.sum(Fe1 * Fe2, -1))


def _components(s):
    return np.stack([s.E11, s.E22, s.E12])


def _assert_angle_deg(actual, expected, atol):
    """Principal directions are axes: compare angles modulo 180 degrees."""
    diff = (np.asarray(actual) - expected + 90.0) % 180.0 - 90.0
    assert np.all(np.abs(diff) <= atol), np.max(np.abs(diff))


def _valid_node_mask(valid, window, min_count):
    """Brute force: node measured and at least ``min_count`` measured points in its (clipped) window."""
    rows, cols = valid.shape
    r = window // 2
    out = np.zeros_like(valid)
    for i in range(rows):
        for j in range(cols):
            block = valid[max(i - r, 0):i + r + 1, max(j - r, 0):j + r + 1]
            out[i, j] = valid[i, j] and block.sum() >= min_count
    return out


# ------------------------------------------------------------------------------ grid, gauge, arguments

def test_triangulate_grid_hand_checked_indices_and_orientation():
    # 2 x 3 grid, flattened  0 1 2 / 3 4 5: cells split along (i, j)-(i+1, j+1).
    np.testing.assert_array_equal(triangulate_grid(2, 3), [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    np.testing.assert_array_equal(triangulate_grid(3, 2), [[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
    tri = triangulate_grid(4, 5)
    assert tri.shape == (2 * 3 * 4, 3)
    # Every triangle is oriented like dX/dj x dX/di: +z for x = j, y = i.
    j, i = np.divmod(np.arange(20), 5)[::-1]
    P = np.stack([j, i, np.zeros(20)], -1).astype(float)
    normal_z = np.cross(P[tri[:, 1]] - P[tri[:, 0]], P[tri[:, 2]] - P[tri[:, 0]])[:, 2]
    np.testing.assert_allclose(normal_z, 1.0)


def test_virtual_strain_gauge_px_hand_numbers():
    assert virtual_strain_gauge_px(15, 5, 65) == 135.0       # 14 steps of 5 px + a 65 px subset
    assert virtual_strain_gauge_px(TRIANGLE_GAUGE_WINDOW, 7, 31) == 38.0  # triangles: one cell, 7 + 31
    assert virtual_strain_gauge_px(3, 2.5, 21.0) == 26.0


@pytest.mark.parametrize("call, match", [
    (lambda X: surface_strain(X[..., :2], X), "X_ref_mm"),
    (lambda X: surface_strain(X[0], X[0]), "X_ref_mm"),
    (lambda X: surface_strain(X, X[:-1]), "X_def_mm"),
    (lambda X: surface_strain(X, X, window=4), "window"),
    (lambda X: surface_strain(X, X, window=1), "window"),
    (lambda X: surface_strain(X, X, window=5.0), "window"),
    (lambda X: surface_strain(X, X, window=5, fit="cubic"), "fit"),
    (lambda X: surface_strain(X, X, fit="quadratic"), "fit"),
    (lambda X: surface_strain(X, X, direction_mm=[1.0, 0.0]), "direction_mm"),
    (lambda X: surface_strain(X, X, direction_mm=[0.0, 0.0, 0.0]), "direction_mm"),
    (lambda X: surface_strain(X, X, window=5, min_valid_fraction=0.0), "min_valid_fraction"),
    (lambda X: surface_strain(X, X, window=5, min_valid_fraction=1.5), "min_valid_fraction"),
    (lambda X: triangle_strain(X, X[:, :-1]), "X_def_mm"),
    (lambda X: triangulate_grid(1, 5), "rows"),
    (lambda X: triangulate_grid(5, 1), "cols"),
    (lambda X: virtual_strain_gauge_px(1, 5, 21), "window"),
    (lambda X: virtual_strain_gauge_px(15, 0, 21), "step_px"),
    (lambda X: virtual_strain_gauge_px(15, 5, -21), "subset_px"),
])
def test_bad_arguments_raise_naming_the_argument(call, match):
    p, R_p, t_p = _plate(6, 7, 1.0, seed=0)
    with pytest.raises(ValueError, match=match):
        call(p @ R_p.T + t_p)


# ------------------------------------------------------------------------- homogeneous, flat, rotated

def _stretch():
    lx, ly = 1.03, 0.98
    F = np.diag([lx, ly, 1.0])
    return F, dict(E=((lx ** 2 - 1) / 2, (ly ** 2 - 1) / 2, 0.0), E1=(lx ** 2 - 1) / 2, E2=(ly ** 2 - 1) / 2,
                   angle=0.0, J=lx * ly)


def _pure_shear():
    g = 0.02
    F = np.array([[1.0, g, 0.0], [g, 1.0, 0.0], [0.0, 0.0, 1.0]])
    return F, dict(E=(g * g / 2, g * g / 2, g), E1=g * g / 2 + g, E2=g * g / 2 - g, angle=45.0, J=1 - g * g)


def _simple_shear():
    g = 0.05
    F = np.array([[1.0, g, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    root = math.sqrt(g ** 4 / 16 + g * g / 4)
    return F, dict(E=(0.0, g * g / 2, g / 2), E1=g * g / 4 + root, E2=g * g / 4 - root,
                   angle=45.0 + 0.5 * math.degrees(math.atan(g / 2)), J=1.0)


@pytest.mark.parametrize("method", METHODS, ids=METHOD_IDS)
@pytest.mark.parametrize("case", [_stretch, _pure_shear, _simple_shear], ids=["stretch", "pure", "simple"])
def test_homogeneous_deformation_of_a_rotated_plate_is_exact_to_1e9(case, method):
    """Stretch / pure shear / simple shear of a plate in a random 3-D pose, followed by a rigid motion."""
    F_p, want = case()
    p, R_p, t_p = _plate(14, 17, 0.5, seed=11)
    Q = Rotation.random(random_state=12).as_matrix()
    X_ref = p @ R_p.T + t_p
    X_def = (p @ F_p.T) @ (Q @ R_p).T + t_p + [4.0, -2.0, 7.0]
    s = surface_strain(X_ref, X_def, **method)
    finite = np.isfinite(s.E11)
    if "window" in method:
        assert finite[2:-2, 2:-2].all()
    else:
        assert finite.all()
    for got, expected in zip(_components(s), want["E"]):
        np.testing.assert_allclose(got[finite], expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.E1[finite], want["E1"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.E2[finite], want["E2"], rtol=0, atol=1e-9)
    _assert_angle_deg(s.angle_deg[finite], want["angle"], atol=1e-6)  # 1e-9 in E -> ~1e-7 deg here
    np.testing.assert_allclose(s.magnitude[finite], math.hypot(want["E1"], want["E2"]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.area_change[finite], want["J"] - 1, rtol=0, atol=1e-9)
    if s.triangles is not None:  # the per-triangle values are exact as well
        for got, expected in zip((s.triangles.E11, s.triangles.E22, s.triangles.E12), want["E"]):
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s.triangles.area_change, want["J"] - 1, rtol=0, atol=1e-9)


def test_triangle_deformation_gradient_maps_edges_and_normal():
    """F = [d1 d2 n][D1 D2 N]^-1 equals the imposed F on the plate plane and maps N to the deformed normal."""
    F_p = np.array([[1.04, 0.03, 0.0], [-0.01, 0.97, 0.0], [0.02, -0.03, 1.0]])  # also tilts the plate
    p, R_p, t_p = _plate(5, 6, 1.0, seed=21)
    X_ref, X_def = p @ R_p.T + t_p, (p @ F_p.T) @ R_p.T + t_p
    tri = triangle_strain(X_ref, X_def)
    F_world = R_p @ F_p @ R_p.T
    n_def = R_p @ np.cross(F_p[:, 0], F_p[:, 1])
    n_def /= np.linalg.norm(n_def)
    for a in range(2):
        np.testing.assert_allclose(tri.F @ R_p[:, a], np.broadcast_to(F_world @ R_p[:, a], (len(tri.F), 3)),
                                   rtol=0, atol=1e-12)
    np.testing.assert_allclose(tri.F @ R_p[:, 2], np.broadcast_to(n_def, (len(tri.F), 3)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(tri.area_ref_mm2, 0.5, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tri.area_change, np.linalg.norm(np.cross(F_p[:, 0], F_p[:, 1])) - 1, atol=1e-12)


@pytest.mark.parametrize("method", METHODS, ids=METHOD_IDS)
def test_frame_is_the_plate_frame_and_direction_mm_rotates_the_components(method):
    F_p, want = _simple_shear()
    p, R_p, t_p = _plate(12, 13, 0.5, seed=31)
    X_ref, X_def = p @ R_p.T + t_p, (p @ F_p.T) @ R_p.T + t_p
    s = surface_strain(X_ref, X_def, **method)
    ok = np.isfinite(s.E11)
    for got, axis in zip((s.e1, s.e2, s.n), R_p.T):
        np.testing.assert_allclose(got[ok], np.broadcast_to(axis, got[ok].shape), rtol=0, atol=1e-12)
    # e1 from a direction 30 deg off the columns (and out of the plane: only its projection counts).
    phi = math.radians(30.0)
    s = surface_strain(X_ref, X_def, direction_mm=R_p @ [math.cos(phi), math.sin(phi), 0.7], **method)
    c, sn = math.cos(phi), math.sin(phi)
    E = np.array([[want["E"][0], want["E"][2]], [want["E"][2], want["E"][1]]])
    Qr = np.array([[c, -sn], [sn, c]])
    E_rot = Qr.T @ E @ Qr
    ok = np.isfinite(s.E11)
    np.testing.assert_allclose(s.e1[ok], np.broadcast_to(R_p @ [c, sn, 0], s.e1[ok].shape), atol=1e-12)
    for got, expected in zip(_components(s), (E_rot[0, 0], E_rot[1, 1], E_rot[0, 1])):
        np.testing.assert_allclose(got[ok], expected, rtol=0, atol=1e-9)
    _assert_angle_deg(s.angle_deg[ok], want["angle"] - 30.0, atol=1e-6)


def test_nodal_value_is_the_area_weighted_mean_of_the_adjacent_triangles():
    """Non-uniform plate spacing and a random (non-homogeneous) deformation: every node's E11, E22, E12 is the
    reference-area-weighted mean of its adjacent triangles' values, and its area change is sum A_def / sum A_ref
    - 1 (each triangle's values recomputed here from its vertices in the plate frame)."""
    rng = np.random.default_rng(131)
    xs, ys = np.cumsum(rng.uniform(0.5, 1.5, 5)), np.cumsum(rng.uniform(0.5, 1.5, 4))
    p = np.stack([*np.meshgrid(xs, ys, indexing="xy"), np.zeros((4, 5))], axis=-1)  # (rows 4, cols 5, 3)
    _, R_p, t_p = _plate(4, 5, 1.0, seed=132)
    X_ref = p @ R_p.T + t_p
    X_def = (p + rng.normal(scale=0.03, size=p.shape)) @ R_p.T + t_p
    s = surface_strain(X_ref, X_def)
    tri = triangulate_grid(4, 5)
    P, Pd = p.reshape(-1, 3)[tri], (X_def.reshape(-1, 3)[tri] - t_p) @ R_p  # deformed, in plate axes
    D = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]], axis=-1)[:, :2, :]  # (n_tri, 2, 2): columns D1, D2
    d = np.stack([Pd[:, 1] - Pd[:, 0], Pd[:, 2] - Pd[:, 0]], axis=-1)        # (n_tri, 3, 2)
    Fe = d @ np.linalg.inv(D)            # columns F e1, F e2 (e1, e2 = plate x, y: the default frame here)
    C = np.swapaxes(Fe, 1, 2) @ Fe
    E_tri = 0.5 * (C - np.eye(2))
    A_ref = 0.5 * np.abs(np.linalg.det(D))
    A_def = 0.5 * np.linalg.norm(np.cross(d[:, :, 0], d[:, :, 1]), axis=-1)
    for node in range(20):
        adjacent = np.any(tri == node, axis=1)
        w = A_ref[adjacent]
        i, j = divmod(node, 5)
        for got, (a, b) in zip((s.E11, s.E22, s.E12), ((0, 0), (1, 1), (0, 1))):
            assert got[i, j] == pytest.approx(np.sum(w * E_tri[adjacent, a, b]) / np.sum(w), abs=1e-12)
        assert s.area_change[i, j] == pytest.approx(np.sum(A_def[adjacent]) / np.sum(w) - 1, abs=1e-12)


# ---------------------------------------------------------------------------------------- rigid motion

@pytest.mark.parametrize("method", METHODS, ids=METHOD_IDS)
@pytest.mark.parametrize("surface", ["plate", "cylinder"])
def test_rigid_motion_gives_zero_strain_to_1e9(surface, method):
    """Random rotations (one of 175 deg) and translations of up to ~100 mm, flat and curved: E = 0, J = 1."""
    if surface == "plate":
        p, R_p, t_p = _plate(15, 18, 0.5, seed=41)
        X_ref = p @ R_p.T + t_p
    else:
        X_ref, _ = _cylinder(15, 18, 50.0, 0.8, Rotation.random(random_state=42).as_matrix(), [3.0, 2.0, 330.0])
    rng = np.random.default_rng(43)
    axis = rng.normal(size=3)
    motions = [Rotation.from_rotvec(np.radians(175.0) * axis / np.linalg.norm(axis)).as_matrix(),
               Rotation.random(random_state=44).as_matrix()]
    for Q in motions:
        X_def = X_ref @ Q.T + rng.uniform(-60, 60, 3)
        s = surface_strain(X_ref, X_def, **method)
        ok = np.isfinite(s.E11)
        assert ok[2:-2, 2:-2].all()
        np.testing.assert_allclose(_components(s)[:, ok], 0.0, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s.area_change[ok], 0.0, rtol=0, atol=1e-9)


# ------------------------------------------------------------------------------------ curved surface

R_CYL = 50.0
F_GENERAL = np.array([[1.02, 0.01, 0.005], [-0.004, 0.97, 0.012], [0.008, -0.006, 1.01]])


@pytest.mark.parametrize("method", [dict(), dict(window=7, fit="linear", min_valid_fraction=0.3),
                                    dict(window=7, fit="quadratic", min_valid_fraction=0.3)],
                         ids=METHOD_IDS)
def test_cylinder_uniform_stretch_is_exact_everywhere(method):
    """X -> lambda X (+ rigid motion): E = (lambda^2 - 1)/2 I in every tangent plane, J = lambda^2.

    Exact for triangles (each is homogeneously stretched, and an isotropic E averages to itself) and for both
    window fits at every node, edges included: a linear fit gives du/dxi_a = (lambda - 1) e_a for whatever
    plane the window has, and E of lambda I is the same in every plane.
    """
    R0 = Rotation.random(random_state=51).as_matrix()
    X_ref, _ = _cylinder(22, 26, R_CYL, 1.0, R0, [5.0, -3.0, 300.0])
    lam = 1.025
    Q = Rotation.random(random_state=52).as_matrix()
    X_def = (lam * X_ref) @ Q.T + [1.0, 2.0, 3.0]
    s = surface_strain(X_ref, X_def, **method)
    assert np.isfinite(s.E11).all()
    np.testing.assert_allclose(s.E11, (lam ** 2 - 1) / 2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.E22, (lam ** 2 - 1) / 2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.E12, 0.0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.area_change, lam ** 2 - 1, rtol=0, atol=1e-9)
    if s.triangles is not None:
        np.testing.assert_allclose(s.triangles.E11, (lam ** 2 - 1) / 2, rtol=0, atol=1e-9)
        np.testing.assert_allclose(s.triangles.area_change, lam ** 2 - 1, rtol=0, atol=1e-9)


def test_cylinder_homogeneous_F_triangles_are_exact_to_1e9():
    """Each triangle of a curved grid under a homogeneous 3-D F: E = 1/2 (F e_a . F e_b - delta_ab) in its plane."""
    R0 = Rotation.random(random_state=61).as_matrix()
    X_ref, _ = _cylinder(12, 15, R_CYL, 1.5, R0, [5.0, -3.0, 300.0])
    X_def = X_ref @ F_GENERAL.T + [1.0, 2.0, 3.0]
    direction = R0[:, 0]
    tri = triangle_strain(X_ref, X_def, direction_mm=direction)
    P = X_ref.reshape(-1, 3)[tri.triangles]
    D1, D2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    N = np.cross(D1, D2)
    N /= np.linalg.norm(N, axis=-1, keepdims=True)
    e1 = direction - (N @ direction)[:, None] * N
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(N, e1)
    for got, expected in zip((tri.E11, tri.E22, tri.E12), _strain_in_frame(F_GENERAL, e1, e2)):
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    J = np.linalg.norm(np.cross(D1 @ F_GENERAL.T, D2 @ F_GENERAL.T), axis=-1) / np.linalg.norm(np.cross(D1, D2),
                                                                                                 axis=-1)
    np.testing.assert_allclose(tri.area_change, J - 1, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tri.n, N, rtol=0, atol=1e-12)


def test_cylinder_linear_window_is_the_exact_strain_of_the_window_plane():
    """Linear window fit on a curved grid under a homogeneous F: exact (1e-9) strain of F in the TLS plane.

    The linear fit of u = (F - I) X over the window gives du/dxi_a = (F - I) e_a exactly, because the TLS
    plane leaves no correlation between the in-plane coordinates and the height h above it. On the uniformly
    sampled cylinder the window's points are mirror-symmetric about the mid-angle of its (clipped) column
    range, so the TLS normal is the radial direction at that mid-angle theta_mid: the strain equals
    1/2 (F e_a . F e_b - delta_ab) in the cylinder frame at theta_mid (= the node's own angle for full windows).
    """
    R0 = Rotation.random(random_state=71).as_matrix()
    rows, cols, step, k = 16, 19, 1.0, 7
    X_ref, theta = _cylinder(rows, cols, R_CYL, step, R0, [5.0, -3.0, 300.0])
    X_def = X_ref @ F_GENERAL.T + [1.0, 2.0, 3.0]
    s = surface_strain(X_ref, X_def, window=k, direction_mm=R0[:, 0], min_valid_fraction=0.3)
    j = np.arange(cols)
    lo, hi = np.maximum(j - k // 2, 0), np.minimum(j + k // 2, cols - 1)
    theta_mid = np.broadcast_to(((lo + hi) / 2 - (cols - 1) / 2) * step / R_CYL, theta.shape)
    e1, e2, n = _cylinder_frame(theta_mid, R0)
    assert np.isfinite(s.E11).all()
    for got, expected in zip(_components(s), _strain_in_frame(F_GENERAL, e1, e2)):
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.n, n, rtol=0, atol=1e-9)


def test_cylinder_window_interior_exact_and_edges_within_the_plane_tilt_bound():
    """Accuracy of the window method against the true surface strain on a cylinder under a homogeneous F.

    * Full windows (interior nodes): the window is symmetric about the node, its plane is the tangent plane,
      and both fits are exact to 1e-9.
    * Clipped windows (the k // 2 nodes next to the left/right edges): the linear fit gives the exact strain
      of the plane tilted by delta = (half the clipped columns) * h / (2 R) <= r h / (2 R) (previous test),
      i.e. the true frame rotated by delta about the axis, so its error is at most 2 delta ||E3||_2
      with E3 = (F^T F - I) / 2: first order in h / R. The quadratic fit corrects the plane with the fitted
      slope of the surface: checked to be at least 1000 x more accurate and of third order (error / 6 at
      least when h halves; the leading term is O((r h / R)^3)).
    """
    R0 = Rotation.random(random_state=81).as_matrix()
    k = 7
    r = k // 2
    E3 = 0.5 * (F_GENERAL.T @ F_GENERAL - np.eye(3))
    norm_E3 = np.linalg.norm(E3, 2)
    quadratic_errors = []
    for step in (1.0, 0.5):
        n_pts = int(round(15 / step)) + 1
        X_ref, theta = _cylinder(n_pts, n_pts, R_CYL, step, R0, [5.0, -3.0, 300.0])
        X_def = X_ref @ F_GENERAL.T + [1.0, 2.0, 3.0]
        truth = np.stack(_strain_in_frame(F_GENERAL, *_cylinder_frame(theta, R0)[:2]))
        interior = np.zeros(theta.shape, bool)
        interior[:, r:-r] = True
        errors = {}
        for fit in ("linear", "quadratic"):
            s = surface_strain(X_ref, X_def, window=k, fit=fit, direction_mm=R0[:, 0], min_valid_fraction=0.3)
            err = np.abs(_components(s) - truth).max(axis=0)
            assert np.isfinite(err).all()
            assert err[interior].max() <= 1e-9
            errors[fit] = err[~interior].max()
        delta = r * step / (2 * R_CYL)
        assert errors["linear"] <= 2 * delta * norm_E3  # ||Q' - Q|| = 2 sin(delta / 2) <= delta
        assert errors["quadratic"] <= 1e-3 * errors["linear"]
        quadratic_errors.append(errors["quadratic"])
    assert quadratic_errors[1] <= quadratic_errors[0] / 6


# ------------------------------------------------------------------------------------------------ holes

def _plate_with_holes(seed):
    """Plate (24 x 27, 0.5 mm) under a homogeneous F + rigid motion, with NaN holes; and the analytic E, J."""
    F_p = np.array([[1.03, 0.02, 0.0], [0.0, 0.985, 0.0], [0.0, 0.0, 1.0]])
    p, R_p, t_p = _plate(24, 27, 0.5, seed=seed)
    Q = Rotation.random(random_state=seed + 1).as_matrix()
    X_ref = p @ R_p.T + t_p
    X_def = (p @ F_p.T) @ (Q @ R_p).T + [1.0, 2.0, 3.0]
    X_ref[8:12, 5:9] = np.nan                        # a hole in the reference
    rng = np.random.default_rng(seed)
    lost = rng.random((24, 27)) < 0.06
    X_def[lost] = np.nan                             # points lost in the deformed state
    X_def[17, 20, 1] = np.nan                        # a single NaN coordinate
    X_ref[3, 22, 2] = np.inf
    E = 0.5 * (F_p.T @ F_p - np.eye(3))
    valid = np.all(np.isfinite(X_ref), -1) & np.all(np.isfinite(X_def), -1)
    return X_ref, X_def, valid, (E[0, 0], E[1, 1], E[0, 1]), F_p[0, 0] * F_p[1, 1] - F_p[0, 1] * F_p[1, 0]


def test_holes_triangles_are_nan_exactly_where_a_vertex_is_missing_and_exact_elsewhere():
    X_ref, X_def, valid, E, J = _plate_with_holes(seed=91)
    s = surface_strain(X_ref, X_def)
    tri = s.triangles
    touches_hole = ~valid.ravel()[tri.triangles].all(axis=1)
    assert touches_hole.any() and not touches_hole.all()
    for values in (tri.E11, tri.E22, tri.E12, tri.E1, tri.magnitude, tri.area_change):
        np.testing.assert_array_equal(np.isnan(values), touches_hole)
    assert np.isnan(tri.F[touches_hole]).all() and np.isfinite(tri.F[~touches_hole]).all()
    for got, expected in zip((tri.E11, tri.E22, tri.E12), E):
        np.testing.assert_allclose(got[~touches_hole], expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tri.area_change[~touches_hole], J - 1, rtol=0, atol=1e-9)
    # Nodes: NaN exactly where no adjacent triangle is valid (brute force over the triangle list).
    has_valid_triangle = np.zeros(valid.size, bool)
    for t in tri.triangles[~touches_hole]:
        has_valid_triangle[t] = True
    has_valid_triangle = has_valid_triangle.reshape(valid.shape)
    np.testing.assert_array_equal(np.isfinite(s.E11), has_valid_triangle)
    assert np.all(has_valid_triangle <= valid)
    for got, expected in zip(_components(s), E):
        np.testing.assert_allclose(got[has_valid_triangle], expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.area_change[has_valid_triangle], J - 1, rtol=0, atol=1e-9)


@pytest.mark.parametrize("fit", ["linear", "quadratic"])
def test_holes_window_is_nan_where_too_few_points_remain_and_exact_elsewhere(fit):
    X_ref, X_def, valid, E, J = _plate_with_holes(seed=101)
    k = 5
    s = surface_strain(X_ref, X_def, window=k, fit=fit)
    expected_defined = _valid_node_mask(valid, k, math.ceil(0.6 * k * k))
    assert expected_defined.any() and not expected_defined[valid].all()
    np.testing.assert_array_equal(np.isfinite(s.E11), expected_defined)
    for got, expected in zip(_components(s), E):
        np.testing.assert_allclose(got[expected_defined], expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.area_change[expected_defined], J - 1, rtol=0, atol=1e-9)
    assert np.isnan(s.e1[~expected_defined]).all()


def test_window_points_on_grid_lines_give_nan():
    """Collinear window points (one grid line, even on a curved arc) are NaN for both fits; points on two grid
    lines are enough for the linear fit (exact on a homogeneous field) but not for the quadratic one."""
    X_ref, _ = _cylinder(9, 12, R_CYL, 1.0, np.eye(3), [0.0, 0.0, 300.0])
    i, j = np.meshgrid(np.arange(9), np.arange(12), indexing="ij")
    for line in (i == 4, i == j, i == j - 2):  # a grid row and two diagonals
        one_line = np.where(line[..., None], X_ref, np.nan)
        for fit in ("linear", "quadratic"):
            # The arc's points span a plane in space (its sagitta), not the surface: no value, not a wrong one.
            s = surface_strain(one_line, X_ref @ F_GENERAL.T, window=7, fit=fit, direction_mm=[1.0, 0.0, 0.0],
                               min_valid_fraction=0.01)
            assert np.isnan(s.E11).all()
    X_def = 1.01 * X_ref
    two_lines = X_ref.copy()
    two_lines[(np.arange(9) != 4) & (np.arange(9) != 5)] = np.nan
    s = surface_strain(two_lines, X_def, window=5, fit="linear", min_valid_fraction=0.01)
    assert np.isfinite(s.E11[4:6, :]).all()
    np.testing.assert_allclose(s.E11[4:6, :], (1.01 ** 2 - 1) / 2, rtol=0, atol=1e-9)
    s = surface_strain(two_lines, X_def, window=5, fit="quadratic", min_valid_fraction=0.01)
    assert np.isnan(s.E11).all()


def test_degenerate_triangles_are_nan_not_wrong():
    """A triangle collapsed to a line (reference or deformed) is NaN; its neighbours stay exact."""
    F_p = np.diag([1.02, 0.99, 1.0])
    p, R_p, t_p = _plate(6, 7, 1.0, seed=111)
    p[2, 3] = 0.5 * (p[2, 2] + p[3, 3])  # (2,2), (2,3), (3,3): vertices of triangle (a, b, d) of cell (2,2)
    X_ref, X_def = p @ R_p.T + t_p, (p @ F_p.T) @ R_p.T + t_p
    tri = triangle_strain(X_ref, X_def)
    flat = 2 * (2 * 6 + 2)  # cell (2, 2) of the 5 x 6 cells, first triangle
    np.testing.assert_array_equal(tri.triangles[flat], [2 * 7 + 2, 2 * 7 + 3, 3 * 7 + 3])
    assert np.isnan(tri.E11[flat]) and np.isnan(tri.area_change[flat])
    others = np.arange(len(tri.E11)) != flat
    np.testing.assert_allclose(tri.E11[others], (1.02 ** 2 - 1) / 2, rtol=0, atol=1e-9)
    # Deformed state collapsing a triangle onto a line: NaN as well.
    p, R_p, t_p = _plate(6, 7, 1.0, seed=112)
    X_ref = p @ R_p.T + t_p
    X_def = X_ref.copy()
    X_def[2, 3] = 0.5 * (X_def[2, 2] + X_def[3, 3])
    assert np.isnan(triangle_strain(X_ref, X_def).E11[flat])


# ---------------------------------------------------------------------------------------- convergence

def _bending_field(x, y, L=20.0):
    """A smooth bending-like displacement on the plate (plate frame) and its analytic gradient."""
    a, b, c, m = 0.004, 0.003, 0.3, 0.002
    u = np.stack([a * L * np.sin(x / L) * np.cos(y / L), b * L * np.sin(y / L) + m * x * y / L,
                  c * L * (1 - np.cos(x / L)) * np.cos(0.5 * y / L)], -1)
    du_dx = np.stack([a * np.cos(x / L) * np.cos(y / L), m * y / L, c * np.sin(x / L) * np.cos(0.5 * y / L)], -1)
    du_dy = np.stack([-a * np.sin(x / L) * np.sin(y / L), b * np.cos(y / L) + m * x / L,
                      -0.5 * c * (1 - np.cos(x / L)) * np.sin(0.5 * y / L)], -1)
    return u, du_dx, du_dy


def test_window_converges_to_a_smooth_field_with_the_stated_order():
    """A 7 x 7 window on a bending-like field, grid refined 0.4 -> 0.2 -> 0.1 mm (plate in a random pose).

    Nodes with a full window: the window is symmetric, so the second-order terms of u do not bias the fitted
    slope and both fits are second order (error / 4 per halving; checked >= 3.5). Edge nodes (one-sided
    windows, min_valid_fraction lowered to keep them): the linear fit is first order (checked >= 1.8 per
    halving), the quadratic fit second order (>= 3.5).
    """
    R_p = Rotation.random(random_state=121).as_matrix()
    errors = {key: [] for key in ("linear", "quadratic", "linear-edge", "quadratic-edge")}
    for step in (0.4, 0.2, 0.1):
        n_pts = int(round(8 / step)) + 1
        i, j = np.meshgrid(np.arange(n_pts), np.arange(n_pts), indexing="ij")
        x, y = j * step, i * step
        p = np.stack([x, y, np.zeros_like(x)], -1)
        u, ux, uy = _bending_field(x, y)
        X_ref, X_def = p @ R_p.T + [2.0, 1.0, 320.0], (p + u) @ R_p.T + [2.0, 1.0, 320.0]
        truth = np.stack([ux[..., 0] + 0.5 * np.sum(ux * ux, -1), uy[..., 1] + 0.5 * np.sum(uy * uy, -1),
                          0.5 * (ux[..., 1] + uy[..., 0] + np.sum(ux * uy, -1))])
        on_y = np.isclose(y, 4.0) | np.isclose(y, 6.0)   # the same physical points on every grid
        interior = (np.isclose(x, 2.0) | np.isclose(x, 4.0)) & on_y
        edge = (j == 0) & on_y
        for fit in ("linear", "quadratic"):
            s = surface_strain(X_ref, X_def, window=7, fit=fit, min_valid_fraction=0.3)
            err = np.abs(_components(s) - truth).max(axis=0)
            errors[fit].append(err[interior].max())
            errors[fit + "-edge"].append(err[edge].max())
    for key, least_ratio in (("linear", 3.5), ("quadratic", 3.5), ("linear-edge", 1.8), ("quadratic-edge", 3.5)):
        e = errors[key]
        assert e[0] / e[1] >= least_ratio and e[1] / e[2] >= least_ratio, (key, e)
    assert errors["linear"][-1] <= 1e-6  # and the values do approach the analytic strain
