"""The paper's three-point bending test, truth side: an FE-deformed speckled beam rendered in stereo.

The beam (:class:`scenes.specimens.beam.BendingSpecimen`, 120 x 30 x 10 mm) stands where the rig's optical axes meet,
its face towards the cameras' bisector, exactly as in the rigid-motion test. It is loaded in three-point
bending (:mod:`scenes.deformation.beam_bending`: a linear-elastic finite-element solution, aluminium, supports 100 mm apart, the
loading nose at mid-span on the top face pushing down = +y of the specimen, i.e. down in the images) at the
paper's loads: a 20 N reference, then 200 -> 2000 N in 200 N steps; every state is rendered in both cameras.

The beam is rendered and given its truth through the generic specimen path, like any specimen from an FE file
(:attr:`BendingTruth.mesh_specimen`: the outer surface of the FE solution's 27-node hexahedra as curved 9-node
faces, the nodal displacements of every load, painted with the specimen's speckle texture): one FE path for every
specimen. Truth of a DIC point (DESIGN §3): the chief ray of the left reference pixel meets the face *deformed by
the 20 N preload* at the material point X0 (:meth:`scenes.specimens.mesh_specimen.MeshSpecimen.material_points_at`);
its true position in state k is ``R (X0 + u_k(X0)) + t``, and its true surface strain relative to the reference
state follows from the face's tangents in both states (:meth:`BendingTruth.strain_truth`).
"""
from __future__ import annotations

import functools
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text

from scenes.optics.camera import SensorSpec
from scenes.deformation.beam_bending import ThreePointBending, three_point_bending_field
from scenes.sensor.noise import SensorNoise
from scenes.specimens.beam import BendingSpecimen
from scenes.optics.projection import focal_length_for_focus_mm, project_points
from workbench.experiments.calibration.views import sensor_spec_for
from workbench.manifest import complete_folder, prepare_folder
from workbench.experiments.rigid_motion.scenes import (BLUR_WARNING_PX, check_specimen_in_view, face_blur_px,
                                                       focus_plane_angle_deg, render_info, render_stereo_states, resolve_rig,
                                                       specimen_reference_pose)
from workbench.rigs import DEFAULT_F_NUMBER, StereoRig

SIDES = ("left", "right")
LENSES = ("thin", "pinhole")
#: Largest distance between the flat pieces rendered and the FE solution's curved faces, px of the face's footprint.
SAGITTA_PX = 0.02
#: Material points within this distance of the plane z = 0 lie on the front face, mm.
FRONT_FACE_TOL_MM = 1e-9
#: The paper's loads (§4.4): a 20 N reference, then 200 -> 2000 N in 200 N steps.
BENDING_LOADS_N = (20.0,) + tuple(200.0 * k for k in range(1, 11))


@dataclass
class BendingTruth:
    """Everything needed to score a stereo-DIC run on the rendered bending images.

    Attributes
    ----------
    specimen : BendingSpecimen
    beam : ThreePointBending, the FE model (geometry, material, supports, mesh)
    specs : {"left"|"right": SensorSpec}, the cameras exactly as rendered
    camera_poses : {"left"|"right": (R_cam_from_world, t_cam_from_world_mm)}; world = left camera frame
    pose : (R_world_from_specimen (3, 3), t_world_from_specimen_mm (3,)) of the (undeformed) beam
    loads_N : (K,) load of every state; state 0 is the reference
    files : K ``{"left": name, "right": name}``
    info : the rest of truth.json
    """

    specimen: BendingSpecimen
    beam: ThreePointBending
    specs: dict[str, SensorSpec]
    camera_poses: dict[str, tuple[np.ndarray, np.ndarray]]
    pose: tuple[np.ndarray, np.ndarray]
    loads_N: np.ndarray
    files: list[dict[str, str]] = field(default_factory=list)
    info: dict = field(default_factory=dict)

    def field(self, k: int):
        """The FE displacement field of state k (from the unloaded beam), specimen frame."""
        return three_point_bending_field(float(self.loads_N[k]), self.beam)

    def project(self, side: str, X_world_mm) -> np.ndarray:
        if side not in SIDES:
            raise ValueError(f"camera must be 'left' or 'right', got {side!r}")
        return project_points(self.specs[side], *self.camera_poses[side], X_world_mm)

    @functools.cached_property
    def mesh_specimen(self):
        """The beam through the generic specimen path (:class:`scenes.specimens.mesh_specimen.MeshSpecimen`): the
        outer surface of its finite-element solution (curved 9-node faces of the 27-node hexahedra), the nodal
        displacements of every load, painted with the specimen's own speckle texture on the front face (the
        material coordinates ``x, y`` of the face are the paint's plane) and its side grey elsewhere. What is
        rendered and what every truth is computed from: one FE path for every specimen."""
        from scenes.deformation.beam_bending import solve_three_point_bending
        from scenes.specimens.mesh_specimen import MeshSpecimen
        from scenes.specimens.surface_mesh import SurfaceMesh
        from scenes.surfaces.paint import Paint

        sp = self.specimen
        m = solve_three_point_bending(self.beam).to_meshio(1.0)
        mesh = SurfaceMesh.from_volume_cells(m.points, {c.type: c.data for c in m.cells}, "the bending beam's FE mesh")
        unit = np.asarray(m.point_data["displacement"], float)
        footprint_mm = float(np.linalg.norm(self.pose[1])) / self.specs["left"].fx
        return MeshSpecimen(mesh, np.stack([unit * float(load) for load in self.loads_N]),
                            Paint(base_grey=sp.side_grey), sagitta_mm=SAGITTA_PX * footprint_mm,
                            texture=sp.texture(), texture_origin_mm=(-0.5 * sp.length_mm, -0.5 * sp.height_mm),
                            texture_size_mm=(sp.length_mm, sp.height_mm))

    def surfaces(self, k: int):
        """What is rendered in state k (world frame): :meth:`scenes.specimens.mesh_specimen.MeshSpecimen.surfaces`."""
        return self.mesh_specimen.surfaces(k, *self.pose)

    def points_of_interest(self, pixels_left_ref) -> tuple[np.ndarray, np.ndarray]:
        """Truth of DIC points defined at pixels of the left reference image (state 0).

        The chief ray of each pixel meets the front face deformed by the reference load at a material point
        (:meth:`scenes.specimens.mesh_specimen.MeshSpecimen.material_points_at`), followed through every state by
        the FE solution's nodal displacements on the face.

        Returns
        -------
        X_specimen_mm : (N, 3) material points on the front face, unloaded coordinates (NaN where the pixel misses
            it)
        X_world_mm : (K, N, 3) their true positions in every state, world (= left camera) frame
        """
        ms = self.mesh_specimen
        face, st = ms.material_points_at(self.specs["left"], *self.camera_poses["left"], *self.pose,
                                         pixels_left_ref, k=0)
        X0 = np.full((len(face), 3), np.nan)
        hit = face >= 0
        X0[hit] = ms.mesh.positions(face[hit], st[hit])
        ok = hit & (np.abs(X0[:, 2]) <= FRONT_FACE_TOL_MM)      # the front face only (not its top/bottom edges)
        X0[~ok] = np.nan
        X0[ok, 2] = 0.0                       # on the plane z = 0 (its faces' interpolation rounds to ~1e-16)
        self._located = (X0[ok].copy(), face[ok], st[ok])     # strain_truth at these points needs no search
        R, t = self.pose
        X_world = np.full((len(self.loads_N), len(X0), 3), np.nan)
        for k in range(len(self.loads_N)):
            X_world[k, ok] = ms.mesh.positions(face[ok], st[ok], ms.displacements_mm[k]) @ np.asarray(R).T + t
        return X0, X_world

    def strain_truth(self, X_specimen_mm, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact surface Green-Lagrange strain of state k relative to the reference state at front-face material
        points (unloaded coordinates), from the FE solution's face
        (:meth:`scenes.specimens.mesh_specimen.MeshSpecimen.surface_strain`).

        Returns
        -------
        E : (N, 2, 2) strain in the orthonormal tangent basis Q of the reference state
        basis_world : (N, 3, 2) Q in the world (= left camera) frame
        area_change : (N,) relative area change ``sqrt(det(I + 2 E)) - 1``
        """
        X = np.asarray(X_specimen_mm, float).reshape(-1, 3)
        n = len(X)
        E = np.full((n, 2, 2), np.nan)
        Q_world = np.full((n, 3, 2), np.nan)
        area = np.full(n, np.nan)
        ok = np.all(np.isfinite(X), axis=1)
        if not ok.any():
            return E, Q_world, area
        ms = self.mesh_specimen
        known = getattr(self, "_located", None)
        if known is not None and np.array_equal(known[0], X[ok]):
            face, st = known[1], known[2]              # the points of the last points_of_interest call
        else:
            face, st = ms.paint_points(X[ok, :2])      # the front face's paint plane is its (x, y)
        found = np.flatnonzero(ok)[face >= 0]
        e, q = ms.surface_strain(face[face >= 0], st[face >= 0], k, reference=0)
        E[found] = e
        Q_world[found] = np.asarray(self.pose[0]) @ q
        area[found] = np.sqrt(np.linalg.det(np.eye(2) + 2.0 * e)) - 1.0
        return E, Q_world, area


# ------------------------------------------------------------------------------------------------------------
def bending_specs(rig: StereoRig, lens: str, focus_world_mm, f_number: float | None = None) -> dict[str, SensorSpec]:
    """The two cameras as rendered: the rig's thin lenses (``scheimpflug`` rig), or a lens focused on the face."""
    if lens not in LENSES:
        raise ValueError(f"lens must be one of {LENSES}, got {lens!r}")
    specs = {}
    for side in SIDES:
        spec = sensor_spec_for(rig, side)
        if lens == "thin":
            if rig.lens_focal_length_mm is not None and f_number in (None, rig.f_number):
                spec = spec.with_(**rig.thin_lens(side))
            else:
                N = DEFAULT_F_NUMBER if f_number is None else float(f_number)
                F = focal_length_for_focus_mm(spec, *rig.pose(side), np.asarray(focus_world_mm, float))
                spec = spec.with_(lens="thin", focal_length_mm=float(F), f_number=N)
        specs[side] = spec
    return specs


def bending_truth(rig: StereoRig, *, lens: str = "thin", f_number: float | None = None, loads_N=BENDING_LOADS_N,
                  specimen: BendingSpecimen | None = None, beam: ThreePointBending | None = None,
                  seed: int = 0) -> BendingTruth:
    """Set up the scene (no rendering): specimen, FE model, cameras; checks that both cameras see the face."""
    loads = np.asarray(loads_N, dtype=float).reshape(-1)
    if loads.size < 2 or not np.all(np.isfinite(loads)) or np.any(loads < 0):
        raise ValueError(f"loads_N must hold a reference and at least one load state (finite, >= 0 N), got {loads_N!r}")
    R0, t0 = specimen_reference_pose(rig)
    if specimen is None:
        specimen = BendingSpecimen.for_pixel_size(float(np.linalg.norm(t0)) / rig.left.fx, seed=seed)
    beam = ThreePointBending() if beam is None else beam
    if (beam.length_mm, beam.height_mm, beam.thickness_mm) != (specimen.length_mm, specimen.height_mm,
                                                             specimen.thickness_mm):
        raise ValueError(f"the FE beam ({beam.length_mm} x {beam.height_mm} x {beam.thickness_mm} mm) and the "
                         f"specimen ({specimen.length_mm} x {specimen.height_mm} x {specimen.thickness_mm} mm) differ")
    specs = bending_specs(rig, lens, t0, f_number)
    check_specimen_in_view(specimen, [(R0, t0)], specs, rig)
    info: dict = {"lens": lens}
    if lens == "thin":
        blur = {side: face_blur_px(specimen, (R0, t0), specs[side], *rig.pose(side)) for side in SIDES}
        angle = {side: focus_plane_angle_deg(specs[side], *rig.pose(side), R0[:, 2]) for side in SIDES}
        info.update(f_number=float(specs["left"].f_number), max_defocus_blur_px=blur, focus_plane_to_face_deg=angle,
                    focal_length_mm={side: specs[side].focal_length_mm for side in SIDES})
        worst = max(blur, key=blur.get)
        if blur[worst] > BLUR_WARNING_PX:
            warnings.warn(f"thin lens: the front face is blurred by up to {blur[worst]:.1f} px in the {worst} image "
                          f"(its plane of sharp focus is {angle[worst]:.0f} deg from the face)", stacklevel=2)
    return BendingTruth(specimen, beam, specs, {side: rig.pose(side) for side in SIDES}, (R0, t0), loads, [], info)


def render_bending(rig: StereoRig | str, out_dir, scale: float = 1.0, lens: str = "thin", spp: int = 64,
                   seed: int = 0, noise_grey: float = 1.0, loads_N=BENDING_LOADS_N, *, f_number: float | None = None,
                   specimen: BendingSpecimen | None = None, beam: ThreePointBending | None = None,
                   progress: bool = True, overwrite: bool = False, mc_target_grey: float | None = None,
                   renderer: str = "auto", optics=None) -> BendingTruth:
    """Render every load state in both cameras: ``left_KK.png``, ``right_KK.png``, ``truth.json`` and
    ``manifest.json`` (truth and manifest last: a folder with a manifest is complete).

    Parameters
    ----------
    rig : StereoRig or a rig name ("scheimpflug", "paper"), built at ``scale``
    lens : "thin" (the rig's lenses; for a rig without lenses one focused on the face centre) or "pinhole"
    spp : samples per pixel (unused with ``mc_target_grey``: adaptive renders at that Monte-Carlo noise, grey);
    renderer : "auto" (the deterministic renderer where a view allows it: a pinhole lens) or "mitsuba"
        (:func:`workbench.experiments.rigid_motion.scenes.render_stereo_states`)
    seed : seeds speckle, sampler and noise; noise_grey : read noise (8-bit grey)
    loads_N : state 0 is the reference (default: 20 N, then 200 -> 2000 N by 200 N)
    overwrite : replace an earlier dataset in ``out_dir`` (deletes exactly the files its manifest lists); without
        it such a folder is refused (:class:`workbench.manifest.DatasetFolderError`)
    optics : :class:`scenes.optics.mtf.Optics`, optional; the lens' diffraction (None: ideal optics)
    """
    rig, rig_scale = resolve_rig(rig, scale)
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    noise = SensorNoise(read_noise_grey=noise_grey, bit_depth=8)
    truth = bending_truth(rig, lens=lens, f_number=f_number, loads_N=loads_N, specimen=specimen, beam=beam, seed=seed)
    out_dir = Path(out_dir)
    digits = max(2, len(str(len(truth.loads_N) - 1)))
    planned = [f"{side}_{k:0{digits}d}.png" for k in range(len(truth.loads_N)) for side in SIDES]
    prepare_folder(out_dir, "bending", planned + ["truth.json"], overwrite=overwrite)
    mc_log: list = []
    render_log: list = []
    files = render_stereo_states(
        truth, truth.surfaces,
        len(truth.loads_N), out_dir, noise, spp=spp, seed=seed, desc=f"rendering bending ({lens})", progress=progress,
        mc_target_grey=mc_target_grey, mc_log=mc_log, renderer=renderer, render_log=render_log, optics=optics)
    truth.files = files
    truth.info.update(render_info(rig, rig_scale, spp, seed, noise_grey, mc_target_grey, mc_log, render_log,
                                  optics))
    atomic_write_text(out_dir / "truth.json", json.dumps(_truth_to_json(truth), indent=1))   # after every image
    complete_folder(out_dir, "bending", [n for names in files for n in names.values()] + ["truth.json"],
                    {"rig": rig.name, "scale": rig_scale, "lens": lens, **truth.info["render"],
                     "loads_N": [float(v) for v in truth.loads_N]})
    return truth


def _truth_to_json(truth: BendingTruth) -> dict:
    R, t = truth.pose
    return {
        "about": "Ground truth of the rendered three-point bending test. World frame = left camera frame (OpenCV "
                 "axes, mm). Specimen pose X_world = R_world_from_specimen @ (X + u_k(X)) + t_world_from_specimen_mm "
                 "with u_k the finite-element displacement at load k (specimen frame: origin at the front-face "
                 "centre, x along the length, y along the height pointing down, z into the material). The FE model "
                 "is in 'beam' (scenes.deformation.beam_bending.ThreePointBending); it is re-solved deterministically on loading. "
                 "Truth of a DIC point: the left reference pixel's chief ray meets the face deformed by the "
                 "reference load at X0; in state k it is at R (X0 + u_k(X0)) + t "
                 "(workbench.experiments.bending.scenes.load_bending_truth(...).points_of_interest).",
        "specimen": {"type": "BendingSpecimen", **truth.specimen.to_dict()},
        "beam": {"type": "ThreePointBending", **truth.beam.to_dict()},
        "cameras": {side: {"sensor_spec": truth.specs[side].to_dict(),
                           "R_cam_from_world": np.asarray(truth.camera_poses[side][0]).tolist(),
                           "t_cam_from_world_mm": np.asarray(truth.camera_poses[side][1]).tolist()}
                    for side in SIDES},
        "R_world_from_specimen": np.asarray(R).tolist(), "t_world_from_specimen_mm": np.asarray(t).tolist(),
        "states": [{"index": k, "load_N": float(p), "files": truth.files[k] if truth.files else None}
                   for k, p in enumerate(truth.loads_N)],
        **truth.info,
    }


def load_bending_truth(out_dir) -> BendingTruth:
    """Read ``truth.json`` written by :func:`render_bending` back into a :class:`BendingTruth`.

    Raises FileNotFoundError when there is no ``truth.json`` and :class:`labio.schema.FileFormatError`
    (a ValueError naming the file and the key) for anything malformed (:mod:`workbench.truth_schema`).
    """
    from workbench import truth_schema as ts

    doc = ts.read_truth(out_dir)
    specimen = ts.specimen(doc["specimen"])
    beam = ts.typed(doc["beam"], ThreePointBending, "ThreePointBending", ts.BEAM_RANGES)
    specs, camera_poses = ts.cameras(doc)
    pose = (doc["R_world_from_specimen"].rotation(), ts.position(doc["t_world_from_specimen_mm"]))
    states = ts.states(doc)
    loads_N = np.array([s["load_N"].number(-1e7, 1e7, unit="N") for s in states])
    files = [ts.files(s) for s in states]
    info = ts.info(doc, ("about", "specimen", "beam", "cameras", "R_world_from_specimen", "t_world_from_specimen_mm",
                         "states"), LENSES)
    return BendingTruth(specimen, beam, specs, camera_poses, pose, loads_N, files, info)
