"""A user's specimen from files (issue 23): curved FE faces, their outer surface, Exodus/VTU/STL input, paint in mm,
pixel rays against the surface, and the generic path against the built-in beam.

Every reference is independent of the code under test: trimesh's volume and ray intersector, meshio's readers,
analytic surfaces and polynomials, and the built-in beam's own truth (:mod:`scenes.optics.projection`)."""
from __future__ import annotations

import warnings

import meshio
import numpy as np
import pytest
import skfem
import trimesh
from skfem.io.meshio import to_meshio

from scenes.specimens.fe_files import SpecimenFileError, read_specimen_file, write_exodus
from scenes.specimens.mesh_specimen import BACK_SIDE, HIDDEN, NO_SURFACE, UNPAINTED, MeshSpecimen
from scenes.surfaces.paint import Paint, layout
from scenes.specimens.ray_surface import cast_rays, refine_on_surface
from scenes.specimens.face_elements import FACE_ELEMENTS
from scenes.specimens.surface_mesh import MeshError, SurfaceMesh

BOX = (np.linspace(0, 20, 3), np.linspace(0, 10, 3), np.linspace(0, 5, 2))


def _box(kind: str) -> meshio.Mesh:
    """A 20 x 10 x 5 mm box of ``kind`` cells: scikit-fem's linear meshes through its meshio converter; the
    quadratic ones get their extra nodes at the linear cell's map of the VTK reference positions (deduplicated)."""
    from scenes.deformation.fe_elements import REFERENCE_ELEMENTS

    if kind == "wedge":          # triangles of the x-y grid extruded over z
        tri = skfem.MeshTri.init_tensor(*BOX[:2])
        nz = len(BOX[2])
        points = np.concatenate([np.column_stack([tri.p.T, np.full(tri.p.shape[1], z)]) for z in BOX[2]])
        layers = [np.column_stack([tri.t.T + j * tri.p.shape[1], tri.t.T + (j + 1) * tri.p.shape[1]])
                  for j in range(nz - 1)]
        return meshio.Mesh(points, [("wedge", np.concatenate(layers))])
    linear = {"tetra10": "tetra", "hexahedron20": "hexahedron", "hexahedron27": "hexahedron"}.get(kind, kind)
    mesh_type = {"tetra": skfem.MeshTet, "hexahedron": skfem.MeshHex}[linear]
    m = to_meshio(mesh_type.init_tensor(*BOX))
    if kind == linear:
        return m
    conn = m.cells[0].data
    ref = REFERENCE_ELEMENTS[kind].nodes
    lin = REFERENCE_ELEMENTS[linear]
    N, _ = lin.shape(ref)                                      # linear shape functions at the quadratic nodes
    X = np.einsum("qa,eai->eqi", N, m.points[conn])            # (E, nq, 3)
    points, inverse = np.unique(np.round(X.reshape(-1, 3), 9), axis=0, return_inverse=True)
    return meshio.Mesh(points, [(kind, inverse.reshape(len(conn), -1))])


# ------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(FACE_ELEMENTS))
def test_face_shape_functions_interpolate_their_polynomials_exactly(name):
    """Each family reproduces every polynomial of its space exactly (to 1e-12): linear for 3/4-node faces,
    quadratic (s^2, st, t^2 as the space holds them) for the others; derivatives too."""
    el = FACE_ELEMENTS[name]
    rng = np.random.default_rng(1)
    st = rng.random((50, 2)) * (0.5 if el.kind == "triangle" else 1.0)
    polys = [lambda s, t: 2 + 3 * s - t, lambda s, t: s * t if el.kind == "square" or el.order == 2 else s]
    if el.order == 2:
        polys += [lambda s, t: s * s - 0.5 * t * t + s * t]
    N, dN = el.shape(st)
    for f in polys:
        nodal = f(el.nodes[:, 0], el.nodes[:, 1])
        assert np.allclose(N @ nodal, f(st[:, 0], st[:, 1]), atol=1e-12, rtol=0)
        h = 1e-6
        ds = (f(st[:, 0] + h, st[:, 1]) - f(st[:, 0] - h, st[:, 1])) / (2 * h)
        assert np.allclose(dN[:, :, 0] @ nodal, ds, atol=1e-7, rtol=0)


@pytest.mark.parametrize("name", list(FACE_ELEMENTS))
def test_surface_evaluation_reproduces_the_face_polynomials(name):
    """``SurfaceMesh.evaluate`` / ``tangents`` (a compiled kernel forming the shape functions per point) give a face's
    polynomials and their (s, t) derivatives exactly (1e-12), nodal values taken from the polynomials; a kernel
    with a wrong monomial, coefficient or derivative would miss them."""
    el = FACE_ELEMENTS[name]
    n = len(el.nodes)
    rng = np.random.default_rng(4)
    points = np.column_stack([el.nodes, np.zeros(n)]) + 0.01 * rng.standard_normal((n, 3))
    mesh = SurfaceMesh(points, {name: np.arange(n)[None, :]})
    st = rng.random((40, 2)) * (0.5 if el.kind == "triangle" else 1.0)
    face = np.zeros(len(st), dtype=np.int64)

    def f(s, t):                                                       # three components, in the face's space
        q = s * t if el.kind == "square" or el.order == 2 else 0.0 * s
        sq = (s * s - 0.5 * t * t) if el.order == 2 else 0.0 * s
        return np.stack([2 + 3 * s - t, q, sq + 0.25 * s], axis=-1)

    def df(s, t):
        q = (t, s) if el.kind == "square" or el.order == 2 else (0.0 * s, 0.0 * s)
        sq = (2 * s, -t) if el.order == 2 else (0.0 * s, 0.0 * s)
        return np.stack([np.stack([3 + 0 * s, -1 + 0 * s], -1), np.stack(q, -1),
                         np.stack([sq[0] + 0.25, sq[1]], -1)], axis=1)

    nodal = f(el.nodes[:, 0], el.nodes[:, 1])
    assert np.allclose(mesh.evaluate(face, st, nodal), f(st[:, 0], st[:, 1]), atol=1e-12, rtol=0)
    assert np.allclose(mesh.tangents(face, st, nodal), df(st[:, 0], st[:, 1]), atol=1e-12, rtol=0)


@pytest.mark.parametrize("kind", ["tetra", "tetra10", "hexahedron", "hexahedron20", "hexahedron27", "wedge"])
def test_outer_surface_of_each_volume_family_is_closed_and_outward(kind):
    """The outer surface, tessellated, is watertight and encloses the box's 1000 mm^3 with outward normals
    (trimesh's volume, positive only for outward faces)."""
    m = _box(kind)
    mesh = SurfaceMesh.from_volume_cells(m.points, {c.type: c.data for c in m.cells}, kind)
    for n in (1, 2):
        tess = mesh.tessellate(n)
        tm = trimesh.Trimesh(mesh.tessellation_positions(tess), tess.triangles, process=False)
        assert tm.is_watertight and tm.is_winding_consistent
        assert tm.volume == pytest.approx(1000.0, rel=1e-12)
    expected = {"tetra": "triangle", "tetra10": "triangle6", "hexahedron": "quad", "hexahedron20": "quad8",
                "hexahedron27": "quad9", "wedge": "triangle"}[kind]
    assert expected in mesh.faces


def test_curved_face_hit_matches_the_analytic_surface():
    """Newton onto a quad9 face sampled from z = a x^2 + b y^2 (which Q2 holds exactly) lands where the ray meets
    that surface (analytic quadratic root) to 1e-9 mm."""
    a, b = 0.01, -0.02
    s = np.array([0, 1, 1, 0, 0.5, 1, 0.5, 0, 0.5])
    t = np.array([0, 0, 1, 1, 0, 0.5, 1, 0.5, 0.5])
    x, y = -10 + 20 * s, -8 + 16 * t
    P = np.column_stack([x, y, a * x ** 2 + b * y ** 2])
    mesh = SurfaceMesh(P, {"quad9": np.arange(9)[None]}, "paraboloid")
    rng = np.random.default_rng(2)
    target = np.column_stack([rng.uniform(-9, 9, 40), rng.uniform(-7, 7, 40)])
    o = np.array([3.0, -2.0, -100.0])
    d = np.column_stack([target - o[:2], np.full(40, 100.0)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # analytic: o + l d on z = a x^2 + b y^2
    A = a * d[:, 0] ** 2 + b * d[:, 1] ** 2
    B = 2 * a * o[0] * d[:, 0] + 2 * b * o[1] * d[:, 1] - d[:, 2]
    C = a * o[0] ** 2 + b * o[1] ** 2 - o[2]
    lam = (-B - np.sqrt(B * B - 4 * A * C)) / (2 * A)
    lam = np.where(np.abs(lam - 100) < 50, lam, (-B + np.sqrt(B * B - 4 * A * C)) / (2 * A))
    X_true = o + lam[:, None] * d
    st0 = np.column_stack([(X_true[:, 0] + 10) / 20, (X_true[:, 1] + 8) / 16]) + 0.01
    st, X = refine_on_surface(mesh, np.zeros(40, int), st0, None, np.repeat(o[None], 40, 0), d, np.eye(3), np.zeros(3))
    assert np.abs(X - X_true).max() < 1e-9


def test_tessellation_sagitta_falls_as_pieces_double():
    """On a bent quad9 face the flat pieces' normal distance falls ~4x per doubling (a chord's sagitta ~ h^2)."""
    s = np.array([0, 1, 1, 0, 0.5, 1, 0.5, 0, 0.5])
    t = np.array([0, 0, 1, 1, 0, 0.5, 1, 0.5, 0.5])
    P = np.column_stack([20 * s, 10 * t, 0.005 * (20 * s) ** 2])        # a gentle bend: 2 mm over 20 mm
    mesh = SurfaceMesh(P, {"quad9": np.arange(9)[None]}, "bent")
    s1, s2, s4 = (mesh.sagitta_mm(n) for n in (1, 2, 4))
    assert s1 / s2 == pytest.approx(4, rel=0.2) and s2 / s4 == pytest.approx(4, rel=0.2)
    assert mesh.pieces_for_sagitta(s1 / 10) == 4


# ------------------------------------------------------------------------------------------------------------
def test_exodus_written_here_reads_in_meshio_and_every_step_here(tmp_path):
    """write_exodus -> meshio reads the same nodes, cells and first step (an independent reader); ours reads every
    step, by index and by time; HEX20's Exodus node order is undone."""
    m = _box("hexahedron20")
    cells = {"hexahedron20": m.cells[0].data}
    U = np.stack([1e-3 * m.points * k for k in range(3)])
    path = tmp_path / "box.e"
    write_exodus(path, m.points, cells, U, times=[0.0, 0.5, 1.0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        back = meshio.read(path)
    assert np.array_equal(back.points, m.points)
    assert back.cells[0].type == "hexahedron20"
    assert np.array_equal(back.point_data["disp_x"], U[0][:, 0])
    sf = read_specimen_file(path, times=[0.5, 1.0])
    assert sf.field_name == ("disp_x", "disp_y", "disp_z") and list(sf.step_indices) == [1, 2]
    assert np.array_equal(sf.displacements_mm, U[1:])
    ref = SurfaceMesh.from_volume_cells(m.points, cells)
    assert all(np.array_equal(sf.mesh.faces[k], ref.faces[k]) for k in ref.faces)


def test_vtu_and_metres(tmp_path):
    """A VTU written by meshio with a displacement in metres: unit = "m" gives mm (x 1000 on nodes and field)."""
    m = _box("tetra10")
    U = 1e-3 * np.column_stack([m.points[:, 0], 0 * m.points[:, 0], 0 * m.points[:, 0]])
    meshio.write(tmp_path / "box.vtu", meshio.Mesh(m.points / 1000, m.cells, point_data={"displacement": U / 1000}))
    sf = read_specimen_file(tmp_path / "box.vtu", unit="m")
    assert np.allclose(sf.mesh.points_mm, m.points, rtol=1e-12) and np.allclose(sf.displacements_mm[0], U, rtol=1e-12)
    with pytest.raises(SpecimenFileError, match=r"box.vtu: the mesh is 0.02 mm across read as 'mm'.*in metres"):
        read_specimen_file(tmp_path / "box.vtu")


def test_stl_with_turned_faces_is_repaired_with_a_warning(tmp_path):
    """An STL box with two faces turned inside out: repaired (trimesh volume back to +1000) and warned."""
    box = trimesh.creation.box(extents=(20, 10, 5))
    faces = box.faces.copy()
    faces[[0, 5]] = faces[[0, 5]][:, ::-1]
    trimesh.Trimesh(box.vertices, faces, process=False).export(tmp_path / "box.stl")
    with pytest.warns(UserWarning, match=r"2 of 12 faces had normals inconsistent"):
        sf = read_specimen_file(tmp_path / "box.stl")
    tess = sf.mesh.tessellate(1)
    tm = trimesh.Trimesh(sf.mesh.tessellation_positions(tess), tess.triangles, process=False)
    assert tm.volume == pytest.approx(1000.0, rel=1e-9)
    assert sf.displacements_mm.shape[0] == 0


def test_bad_specimen_files_name_the_file_and_the_fault(tmp_path):
    m = _box("tetra")
    U = np.stack([np.zeros_like(m.points)] * 2)
    path = tmp_path / "box.e"
    write_exodus(path, m.points, {"tetra": m.cells[0].data}, U, times=[0.0, 1.0])
    with pytest.raises(SpecimenFileError, match=r"box.e: no point data named 'u'; available point data: disp_x"):
        read_specimen_file(path, displacement="u")
    with pytest.raises(SpecimenFileError, match=r"box.e: no time step 5; the file has 2 steps \(0: t=0, 1: t=1\)"):
        read_specimen_file(path, steps=[5])
    U[1, 3, 2] = np.nan
    write_exodus(tmp_path / "nan.e", m.points, {"tetra": m.cells[0].data}, U)
    with pytest.raises(SpecimenFileError, match=r"nan.e: displacement .* at step 1 is not finite at 1 nodes"):
        read_specimen_file(tmp_path / "nan.e")
    (tmp_path / "empty.stl").write_text("solid empty\nendsolid empty\n")
    with pytest.raises(SpecimenFileError, match=r"empty.stl: .*no faces"):
        read_specimen_file(tmp_path / "empty.stl")
    meshio.write(tmp_path / "lines.vtu", meshio.Mesh(m.points, [("line", np.array([[0, 1]]))]))
    with pytest.raises(SpecimenFileError, match=r"lines.vtu: no faces or volume cells of a supported type.*line"):
        read_specimen_file(tmp_path / "lines.vtu")
    mesh = SurfaceMesh.from_volume_cells(m.points, {"tetra": m.cells[0].data})
    with pytest.raises(ValueError, match=r"displacements must be \(K, 18, 3\)"):
        MeshSpecimen(mesh, np.zeros((1, 17, 3)))


def test_non_manifold_volume_mesh_is_refused():
    m = _box("tetra")
    conn = m.cells[0].data
    with pytest.raises(MeshError, match=r"shared by more than two cells"):
        SurfaceMesh.from_volume_cells(m.points, {"tetra": np.concatenate([conn, conn[:1], conn[:1]])}, "bad")


# ------------------------------------------------------------------------------------------------------------
def test_sprayed_paint_stretch_is_one_over_cosine():
    """A plane inclined 60 deg to the spray gets speckles stretched 2x; one facing it 1x; one turned away none."""
    c, s = np.cos(np.radians(60)), np.sin(np.radians(60))
    V = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0],                 # facing the spray (normal -z)
                  [20, 0, 0], [20, 10, 0], [20 + 10 * c, 0, 10 * s],  # normal 60 deg from -z
                  [40, 0, 0], [40, 10, 0], [40, 0, -10]], float)      # edge-on (normal along x)
    T = np.array([[0, 2, 1], [3, 4, 5], [6, 7, 8]])
    lay = layout(Paint(max_angle_deg=80), V, T)
    assert lay.painted.tolist() == [True, True, False]
    assert lay.stretch[:2] == pytest.approx([1.0, 2.0], rel=1e-12)


def test_wrapped_cylinder_paint_is_arc_length():
    """Wrapped on a cylinder of radius 57 mm: u = R theta exactly at the vertices, no stretch, seam at the back."""
    cyl = trimesh.creation.cylinder(radius=57.0, height=40.0, sections=180)
    lay = layout(Paint(method="wrapped", axis_point_mm=(0, 0, 0), axis_direction=(0, 0, 1), direction=(0, 1, 0)),
                 cyl.vertices, cyl.faces)
    V = cyl.vertices
    used = np.unique(cyl.faces[lay.painted])
    theta = np.arctan2(V[used, 0], -V[used, 1])       # from -direction (e0 = -y) towards e1 = z x (-y) = +x
    assert np.allclose(lay.uv_mm[used, 0], 57.0 * theta, atol=1e-9)
    assert np.allclose(lay.stretch[lay.painted], 1.0, atol=1e-9)
    assert np.abs(theta).max() < np.radians(171)


def test_wrapped_cylinder_paint_covers_only_faces_within_max_angle():
    """max_angle_deg 50: the painted faces are exactly those whose centre lies within 50 deg of -direction round
    the axis (analytic: a face's outer normal on a cylinder is its centre's radial direction)."""
    cyl = trimesh.creation.cylinder(radius=57.0, height=40.0, sections=180)
    lay = layout(Paint(method="wrapped", axis_point_mm=(0, 0, 0), axis_direction=(0, 0, 1), direction=(0, 1, 0),
                       max_angle_deg=50.0), cyl.vertices, cyl.faces)
    centre = cyl.vertices[cyl.faces].mean(axis=1)
    side = np.abs(cyl.face_normals[:, 2]) < 1e-9                 # the lateral faces, not the end caps
    angle = np.degrees(np.arctan2(np.abs(centre[:, 0]), -centre[:, 1]))
    expected = side & (angle < 50.0 - 1.0)
    assert lay.painted[expected].all()
    assert not lay.painted[side & (angle > 50.0 + 1.0)].any()
    assert not lay.painted[~side].any()


# ------------------------------------------------------------------------------------------------------------
def _camera(scale=0.1):
    from workbench.experiments.calibration.views import sensor_spec_for
    from workbench.rigs import get_rig

    rig = get_rig("paper", scale)
    return rig, {side: (sensor_spec_for(rig, side), *rig.pose(side)) for side in ("left", "right")}


def test_ray_cast_matches_trimesh_ray_intersector():
    """Every pixel ray of a 246 x 206 view against a tetra box: the same nearest triangle and hit point (1e-9 mm)
    as trimesh's own ray-triangle intersector, and misses where it misses."""
    from scenes.specimens.ray_surface import pixel_centre_rays

    rig, cams = _camera(0.1)
    spec, Rc, tc = cams["left"]
    m = _box("tetra")
    mesh = SurfaceMesh.from_volume_cells(m.points, {"tetra": m.cells[0].data})
    tess = mesh.tessellate(1)
    V = mesh.tessellation_positions(tess) - [10, 5, 0] + [0, 0, 370.0]    # in front of the left camera
    V = (V - tc) @ Rc                                                      # camera frame -> world
    hits = cast_rays(spec, Rc, tc, V, tess.triangles)
    xy = pixel_centre_rays(spec)
    d_cam = np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], axis=2).reshape(-1, 3)
    d = d_cam @ Rc
    o = np.repeat((-Rc.T @ tc)[None], len(d), 0)
    tm = trimesh.Trimesh(V, tess.triangles, process=False)
    locs, rays, tris = trimesh.ray.ray_triangle.RayMeshIntersector(tm).intersects_location(o, d, multiple_hits=False)
    hit = hits.triangle.reshape(-1) >= 0
    assert set(np.flatnonzero(hit)) == set(rays.tolist()) and hit.sum() > 1000
    ours = (hits.depth_mm.reshape(-1)[rays][:, None] * d_cam[rays] - tc) @ Rc
    assert np.abs(ours - locs).max() < 1e-9


def test_occluded_points_are_masked_hidden():
    """A plate with a block in front of it: plate pixels of the left image whose line of sight to the right camera
    passes through the block are HIDDEN (checked with trimesh's intersector), the rest of the plate is measurable."""
    rig, cams = _camera(0.1)
    plate = trimesh.creation.box(extents=(60, 40, 2))
    plate.apply_translation([0, 0, 1])
    block = trimesh.creation.box(extents=(6, 6, 6))
    block.apply_translation([0, 0, -30])
    both = trimesh.util.concatenate([plate, block])
    mesh = SurfaceMesh(both.vertices, {"triangle": both.faces}, "plate+block")
    from workbench.experiments.rigid_motion.scenes import specimen_reference_pose

    R0, t0 = specimen_reference_pose(rig)
    spec = MeshSpecimen(mesh, np.zeros((1, len(mesh.points_mm), 3)), Paint(max_angle_deg=30))
    pt = spec.pixel_truth(cams, R0, t0)
    on_plate = (pt.face >= 0) & (pt.face < len(plate.faces))
    assert np.any(on_plate & (pt.mask & HIDDEN > 0)) and np.any(on_plate & (pt.mask == 0))
    # independent: cast from each plate point towards the right camera with trimesh
    rows, cols = np.nonzero(on_plate & ((pt.mask & np.uint8(255 - HIDDEN)) == 0))
    pick = np.random.default_rng(0).choice(len(rows), 400, replace=False)
    X = pt.X_world_mm[0, rows[pick], cols[pick]].astype(float)
    world = trimesh.Trimesh(both.vertices @ R0.T + t0, both.faces, process=False)
    C = -cams["right"][1].T @ cams["right"][2]
    d = C - X
    dist = np.linalg.norm(d, axis=1)
    locs, ray_idx, _ = trimesh.ray.ray_triangle.RayMeshIntersector(world).intersects_location(
        X + 1e-6 * d, d / dist[:, None], multiple_hits=True)
    blocked = np.zeros(len(X), bool)
    blocked[ray_idx[np.linalg.norm(locs - X[ray_idx], axis=1) > 0.05]] = True
    hidden = pt.mask[rows[pick], cols[pick]] & HIDDEN > 0
    agree = hidden == blocked
    # near the block's silhouette the 2 x 2 pixel test counts points hidden that a ray just misses: never the reverse
    assert not np.any(blocked & ~hidden)
    assert agree.mean() > 0.95


def test_beam_through_the_generic_path_equals_the_built_in_path():
    """The FE beam read as a volume mesh, painted with the built-in texture: the material points of the left
    reference pixels and their images in both cameras in every state equal the built-in truth to 1e-6 px; the
    exact renders agree to well under Monte-Carlo noise (0.05 grey RMS; Mitsuba at 64 spp is ~1 grey)."""
    from scenes.rendering.exact import render_view_exact
    from scenes.deformation.beam_bending import solve_three_point_bending
    from workbench.experiments.bending.scenes import bending_truth
    from workbench.rigs import get_rig

    rig = get_rig("paper", 0.2)
    bt = bending_truth(rig, lens="pinhole", loads_N=(20.0, 2000.0))
    sp = bt.specimen
    m = solve_three_point_bending(bt.beam).to_meshio(1.0)
    mesh = SurfaceMesh.from_volume_cells(m.points, {c.type: c.data for c in m.cells}, "beam")
    U = np.stack([m.point_data["displacement"] * load for load in bt.loads_N])
    ms = MeshSpecimen(mesh, U, Paint(base_grey=sp.side_grey), texture=sp.texture(),
                      texture_origin_mm=(-sp.length_mm / 2, -sp.height_mm / 2),
                      texture_size_mm=(sp.length_mm, sp.height_mm))
    cams = {s: (bt.specs[s], *bt.camera_poses[s]) for s in ("left", "right")}
    pt = ms.material_points(*cams["left"], *bt.pose)
    ys, xs = np.mgrid[0:pt.face.shape[0]:5, 0:pt.face.shape[1]:5]
    ok = pt.face[ys, xs] >= 0
    face, st = pt.face[ys, xs][ok], pt.st[ys, xs][ok]
    X, xy, visible = ms.follow(face, st, cams, *bt.pose)
    _, X_builtin = bt.points_of_interest(np.column_stack([xs[ok], ys[ok]]).astype(float))
    inside = np.all(np.isfinite(X_builtin[0]), axis=1)
    assert inside.sum() > 2000 and inside.mean() > 0.97    # the rest: pixels on the beam's top/bottom edge faces
    for k in range(2):
        for side in ("left", "right"):
            seen = visible[k] & inside
            assert np.abs(xy[side][k][seen] - bt.project(side, X_builtin[k][seen])).max() < 1e-6
    assert (pt.mask[ys, xs][ok][inside] & (NO_SURFACE | BACK_SIDE | UNPAINTED) == 0).all()
    for k in range(2):
        built_in = sp.surfaces(*bt.pose, texture=sp.texture(), displacement_mm=bt.field(k))
        a, _ = render_view_exact(bt.specs["left"], *bt.camera_poses["left"], built_in)
        b, info = render_view_exact(bt.specs["left"], *bt.camera_poses["left"], ms.surfaces(k, *bt.pose))
        assert info["back_faces_culled"]
        assert np.sqrt(np.mean((a - b) ** 2)) < 0.05


def test_external_exodus_sample_from_pyvale_reads_like_meshio_reads_it():
    """pyvale's MOOSE plate (tests/data/pyvale, MIT): a 2-D QUAD4 model in metres. Refused as mm (named), read in m:
    100 x 50 mm, its in-plane displacement pair completed with z = 0; every step equals meshio's own Exodus reading
    of the same nodal variables (meshio reads the first step; netCDF4 directly gives the rest)."""
    from pathlib import Path

    import netCDF4

    path = Path(__file__).parent / "data" / "pyvale" / "case18_1_out_first3.e"
    with pytest.raises(SpecimenFileError, match=r"case18_1_out_first3.e: the mesh is 0.1 mm across read as 'mm'"):
        read_specimen_file(path)
    sf = read_specimen_file(path, unit="m")
    assert sf.field_name == ("disp_x", "disp_y", "disp_z") and sf.info["two_dimensional"] == ["disp_z"]
    assert list(sf.times) == [0.0, 5.0, 10.0] and "quad" in sf.mesh.faces
    assert np.ptp(sf.mesh.points_mm, axis=0)[:2] == pytest.approx([100.0, 50.0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        back = meshio.read(path)
    assert np.allclose(sf.displacements_mm[0][:, 0], 1000 * back.point_data["disp_x"], rtol=0, atol=0)
    with netCDF4.Dataset(path) as ds:
        names = [netCDF4.chartostring(r).item().strip() for r in ds.variables["name_nod_var"][:]]
        raw_y = ds.variables[f"vals_nod_var{names.index('disp_y') + 1}"][:]
    assert np.array_equal(sf.displacements_mm[:, :, 1], 1000 * np.asarray(raw_y))
    assert np.all(sf.displacements_mm[:, :, 2] == 0)


@pytest.mark.parametrize("fmt, suffix", [("gmsh", ".msh"), ("abaqus", ".inp")])
def test_gmsh_and_abaqus_files_written_by_meshio(tmp_path, fmt, suffix):
    """A tetra10 box written by meshio as Gmsh .msh and Abaqus .inp reads back as the same curved outer surface
    (1000 mm^3, watertight) with meshio's own node coordinates."""
    m = _box("tetra10")
    path = tmp_path / f"box{suffix}"
    meshio.write(path, meshio.Mesh(m.points, m.cells), file_format=fmt)
    sf = read_specimen_file(path)
    back = meshio.read(path)
    assert np.allclose(sf.mesh.points_mm, back.points[:, :3])
    assert "triangle6" in sf.mesh.faces and sf.displacements_mm.shape[0] == 0
    tess = sf.mesh.tessellate(2)
    tm = trimesh.Trimesh(sf.mesh.tessellation_positions(tess), tess.triangles, process=False)
    assert tm.is_watertight and tm.volume == pytest.approx(1000.0, rel=1e-12)


def test_pvd_member_with_another_mesh_is_refused(tmp_path):
    """A .pvd whose second step is on another mesh (a moving or remeshed result) is refused naming the member."""
    a, b = _box("tetra"), _box("hexahedron")
    meshio.write(tmp_path / "s0.vtu", meshio.Mesh(a.points, a.cells, point_data={"displacement": 0 * a.points}))
    meshio.write(tmp_path / "s1.vtu", meshio.Mesh(b.points * 1.01, b.cells, point_data={"displacement": 0 * b.points}))
    (tmp_path / "r.pvd").write_text('<?xml version="1.0"?><VTKFile type="Collection"><Collection>'
                                    '<DataSet timestep="0" file="s0.vtu"/><DataSet timestep="1" file="s1.vtu"/>'
                                    '</Collection></VTKFile>')
    with pytest.raises(SpecimenFileError, match=r"r.pvd: s1.vtu has another mesh than the first step"):
        read_specimen_file(tmp_path / "r.pvd")
