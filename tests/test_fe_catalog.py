"""The specimen catalog's FE models (issue 23) against independent references: Lame's thick-walled tube, Howland's
hole in a long strip, the notched coupon's equilibrium, and the exact volumes of the curved geometries."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from scenes.specimens.catalog import notched_coupon, plate_with_hole, pressurised_cylinder, write_pvd
from scenes.specimens.fe_files import read_specimen_file
from fe_reference import FEMeshField
from scenes.specimens.surface_mesh import SurfaceMesh


def _volume(result) -> float:
    mesh = SurfaceMesh.from_volume_cells(result.points_mm, {"hexahedron27": result.cells}, result.name)
    tess = mesh.tessellate(16)          # the flat pieces' chords then cut < 1e-4 of a tube's volume
    tm = trimesh.Trimesh(mesh.tessellation_positions(tess), tess.triangles, process=False)
    assert tm.is_watertight
    return tm.volume


def test_tube_matches_lame_and_its_curved_volume():
    """Open-ended tube under internal pressure: the outer radial displacement equals Lame's 2 p a^2 b / (E (b^2 - a^2))
    to 1e-5 (relative) everywhere on the outer surface; the mirrored curved mesh encloses pi (b^2 - a^2) L to 1e-4."""
    r = pressurised_cylinder(n_around=6, n_axial=4)
    b, a = r.info["outer_radius_mm"], r.info["inner_radius_mm"]
    P, U = r.points_mm, r.displacements_mm[1]
    radius = np.hypot(P[:, 0], P[:, 2] - b)
    outer = np.abs(radius - b) < 1e-9
    assert outer.sum() > 100
    ur = (U[outer, 0] * P[outer, 0] + U[outer, 2] * (P[outer, 2] - b)) / radius[outer]
    lame = 2 * r.times[1] * a * a * b / (r.info["E_mpa"] * (b * b - a * a))
    assert np.abs(ur / lame - 1).max() < 1e-5
    assert _volume(r) == pytest.approx(np.pi * (b * b - a * a) * r.info["length_mm"], rel=1e-4)


def test_plate_hole_concentration_matches_howland():
    """The strain concentration E eps_xx / sigma at the hole's side (where the stress is uniaxial), averaged through
    the thickness (Simpson), equals Howland's long-strip value for d/W = 0.2 (gross Kt 3.14) within 1 %; the plate
    encloses (L W - pi a^2) T to 1e-4."""
    r = plate_with_hole()
    f = FEMeshField(r.points_mm, {"hexahedron27": r.cells}, r.displacements_mm[1])
    a, T, E, sigma = r.info["hole_radius_mm"], r.info["thickness_mm"], r.info["E_mpa"], r.times[1]
    z = np.array([0.0, T / 4, T / 2])
    G = f.gradient(np.column_stack([np.full(3, 1e-9), np.full(3, a + 1e-9), z]))
    kt = E * G[:, 0, 0] / sigma
    kt_mean = (kt[0] + 4 * kt[1] + kt[2]) / 6
    assert kt_mean == pytest.approx(3.14, rel=0.01)
    assert _volume(r) == pytest.approx((r.info["length_mm"] * r.info["width_mm"] - np.pi * a * a) * T, rel=1e-4)


def test_coupon_carries_its_load_through_the_notched_section():
    """Equilibrium of the notched coupon: the axial force through the net section x = 0 (Gauss integral of
    E-law stresses from the FE gradient) equals the remote stress times the gross section within 0.5 %; volume exact."""
    r = notched_coupon()
    f = FEMeshField(r.points_mm, {"hexahedron27": r.cells}, r.displacements_mm[1])
    half = 0.5 * r.info["width_mm"] - r.info["notch_radius_mm"]
    T = r.info["thickness_mm"]
    gy, wy = np.polynomial.legendre.leggauss(40)
    gz, wz = np.polynomial.legendre.leggauss(6)
    Y, Z = np.meshgrid(half * gy, 0.5 * T * (gz + 1), indexing="ij")
    W = np.outer(wy * half, wz * 0.5 * T)
    G = f.gradient(np.column_stack([np.full(Y.size, 1e-9), Y.ravel(), Z.ravel()]))
    E, nu = r.info["E_mpa"], r.info["nu"]
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    eps = 0.5 * (G + np.transpose(G, (0, 2, 1)))
    sxx = lam * np.trace(eps, axis1=1, axis2=2) + 2 * mu * eps[:, 0, 0]
    force = float(np.sum(sxx * W.ravel()))
    assert force == pytest.approx(r.times[1] * r.info["width_mm"] * T, rel=5e-3)
    rn = r.info["notch_radius_mm"]
    assert _volume(r) == pytest.approx((r.info["length_mm"] * r.info["width_mm"] - np.pi * rn * rn) * T, rel=1e-4)


def test_catalog_command_writes_a_collection_meshio_and_our_reader_agree_on(tmp_path, capsys):
    """`workbench catalog` writes a .pvd of one VTU per step and a scenario naming it; read back, the steps'
    displacements are the FE's (meshio reads the VTU members independently)."""
    import meshio

    from workbench.cli import main

    assert main(["catalog", "notched_coupon", "--out", str(tmp_path / "c")]) == 0
    assert "notched_coupon.pvd" in capsys.readouterr().out
    sf = read_specimen_file(tmp_path / "c" / "notched_coupon.pvd")
    assert list(sf.times) == [0.0, 40.0, 80.0, 120.0]
    member = meshio.read(tmp_path / "c" / "notched_coupon_02.vtu")
    assert np.array_equal(sf.displacements_mm[2], member.point_data["displacement"])
    assert 'mesh = "notched_coupon.pvd"' in (tmp_path / "c" / "scenario.toml").read_text()


def test_write_pvd_is_atomic_per_file(tmp_path):
    r = notched_coupon(n_x=4, n_y=2)
    pvd = write_pvd(r, tmp_path)
    assert not list(tmp_path.glob(".*.tmp"))
    assert pvd.read_text().count("<DataSet") == len(r.times)
