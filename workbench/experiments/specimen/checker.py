"""A checker painted on a curved surface: where its corners appear in the rendered image against where the truth
says they are (issue 23's geometry check of the specimen path).

The catalog's tube (outer radius 57 mm) carries a checker printed on a sheet wrapped round it (squares of
``square_mm`` in arc length and along the axis). Its front line is put on the left camera's central pixel column
at ``distance_mm``, so the view spans more than +-50 deg of arc. The truth of a corner is the material point of the
curved FE surface whose paint coordinates are a multiple of the square (:meth:`scenes.specimens.mesh_specimen.MeshSpecimen.
paint_points`), projected by the truth side's camera; the render is the deterministic one (exact polygon coverage
of the printed squares on the surface's flat pieces, occluding edges traced by Mitsuba). The instrument's corner
refinement (:func:`measurement.calibration.detection.refine_corners_saddle`, started 0.3 px off) finds the corners
in the image. Their agreement measures the whole render path on a curved surface: tessellation, paint mapping,
projection, rasterisation.
"""
from __future__ import annotations

import numpy as np


def checker_corner_agreement(scale: float = 1.0, *, square_mm: float = 2.0, arc_deg: float = 50.0,
                             distance_mm: float = 420.0, sagitta_px: float = 0.02, angle_deg: float = 20.0,
                             half_size_px: float | None = None, seed: int = 0, image=None) -> dict:
    """Render the left view of the checkered tube and compare every corner within +-``arc_deg`` of arc.

    ``half_size_px``: the corner fit's window half-width (default: the instrument's, 0.35 x the corner spacing within
    [3, 15] px). ``image``: a render of this scene to reuse (``result["image"]`` of an earlier call).

    Returns ``{"corners", "mean_px", "max_px", "rms_px", "mean_offset_px" (2,), "arc_deg" [min, max] of the corners
    used, "render_s", "renderer", "known_fraction", "pieces_per_face_edge", "image_size"}``.
    """
    import time

    from measurement.calibration.detection import refine_corners_saddle
    from scenes.rendering.render import render_views
    from scenes.specimens.catalog import pressurised_cylinder
    from scenes.specimens.mesh_specimen import MeshSpecimen
    from scenes.surfaces.paint import Paint
    from scenes.specimens.surface_mesh import SurfaceMesh
    from scenes.optics.projection import pixel_rays, project_points
    from workbench.experiments.calibration.views import sensor_spec_for
    from workbench.experiments.rigid_motion.scenes import specimen_reference_pose
    from workbench.rigs import get_rig

    rig = get_rig("paper", scale)
    spec = sensor_spec_for(rig, "left")
    R_c, t_c = rig.pose("left")
    o, d = pixel_rays(spec, R_c, t_c, np.array([[0.5 * (spec.width - 1), 0.5 * (spec.height - 1)]]))
    centre = o[0] + distance_mm * d[0]
    R0, t0 = specimen_reference_pose(rig, centre_world_mm=centre)
    fe = pressurised_cylinder()
    mesh = SurfaceMesh.from_volume_cells(fe.points_mm, {"hexahedron27": fe.cells}, "tube")
    R_axis = fe.info["outer_radius_mm"]
    paint = Paint(kind="checker", method="wrapped", checker_mm=square_mm, axis_point_mm=(0.0, 0.0, R_axis),
                  axis_direction=(0.0, 1.0, 0.0), seed=seed, angle_deg=angle_deg)
    footprint = distance_mm / spec.fx
    specimen = MeshSpecimen(mesh, fe.displacements_mm[:1], paint, sagitta_mm=sagitta_px * footprint)
    start = time.perf_counter()
    if image is None:
        auto = render_views([(spec, (R_c, t_c))], specimen.surfaces(0, R0, t0), seed=seed, exposure_grey=255.0,
                            mc_target_grey=0.1)[0]
        image, renderer, known = auto.image_grey, auto.renderer, float(auto.known_fraction)
    else:
        image, renderer, known = image["image"], image["renderer"], image["known_fraction"]
    render_s = time.perf_counter() - start
    # the corners: multiples of the square in the (turned) paint plane, within the arc and the tube's length
    r = specimen.layout.radius_mm
    reach = np.radians(arc_deg + 10) * r + 0.5 * fe.info["length_mm"]
    n = int(np.ceil(reach / square_mm))
    I, J = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1))
    face, st = specimen.paint_points(np.column_stack([I.ravel(), J.ravel()]) * square_mm)
    ok = face >= 0
    X_spec = np.full((face.size, 3), np.nan)
    X_spec[ok] = specimen.mesh.positions(face[ok], st[ok])
    theta = np.degrees(np.arctan2(X_spec[:, 0], R_axis - X_spec[:, 2]))     # 0 on the front line
    truth = project_points(spec, R_c, t_c, X_spec @ R0.T + t0)
    margin = 12
    usable = ok & np.all(np.isfinite(truth), axis=1) & (truth[:, 0] > margin) & (truth[:, 1] > margin) \
        & (truth[:, 0] < spec.width - 1 - margin) & (truth[:, 1] < spec.height - 1 - margin) \
        & (np.abs(X_spec[:, 1]) < 0.5 * fe.info["length_mm"] - square_mm)
    grid_ok = usable.reshape(I.shape)
    t_grid = truth.reshape(I.shape + (2,))
    # each corner is refined as the centre of its own 3 x 3 block of neighbours (the refinement takes the lines'
    # directions from the neighbours; a turned checker's corners in view do not form one rectangle)
    centres = [(i, j) for i in range(1, I.shape[0] - 1) for j in range(1, I.shape[1] - 1)
               if grid_ok[i - 1:i + 2, j - 1:j + 2].all() and abs(theta.reshape(I.shape)[i, j]) <= arc_deg]
    if len(centres) < 9:
        raise RuntimeError("too few checker corners in view")
    found, true_xy, used_theta = [], [], []
    for i, j in centres:
        block = t_grid[i - 1:i + 2, j - 1:j + 2].reshape(-1, 2)
        refined = refine_corners_saddle(image, block + np.array([0.3, -0.3]), pattern_size=(3, 3),
                                        half_size_px=half_size_px)
        found.append(refined[4])
        true_xy.append(block[4])
        used_theta.append(theta.reshape(I.shape)[i, j])
    found, true_xy = np.array(found), np.array(true_xy)
    err = found - true_xy
    dist = np.linalg.norm(err, axis=1)
    return {"corners": int(len(dist)), "mean_px": float(dist.mean()), "max_px": float(dist.max()),
            "rms_px": float(np.sqrt(np.mean(dist ** 2))), "mean_offset_px": err.mean(axis=0).tolist(),
            "arc_deg": [float(np.min(used_theta)), float(np.max(used_theta))], "render_s": round(render_s, 2),
            "worst_corner_arc_deg": float(np.asarray(used_theta)[int(np.argmax(dist))]),
            "max_px_within_40deg": float(dist[np.abs(np.asarray(used_theta)) <= 40].max()),
            "renderer": renderer, "known_fraction": known, "half_size_px": half_size_px,
            "image": {"image": image, "renderer": renderer, "known_fraction": known},
            "pieces_per_face_edge": int(specimen.tessellation.n), "image_size": [spec.width, spec.height],
            "square_px": float(square_mm / footprint)}
