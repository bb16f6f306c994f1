"""A specimen of one's own, truth side: a user's mesh or FE result placed before the rig, painted, rendered in
stereo, with the exact truth of every pixel (:mod:`scenes.specimens.mesh_specimen`).

The scenario's ``[specimen]`` section (:class:`workbench.scenario.SpecimenConfig`) names the file, its field, unit
and steps, where the mesh goes and how it is painted. The mesh's own frame is turned by ``rotation_deg`` and its
``origin_mm`` put where the rig's optical axes meet, its ``-z`` towards the cameras (as the built-in beam's front
face): the *specimen frame* of the truth. State ``k`` is the ``k``-th chosen FE step, then ``rigid_states`` rigid
moves of the last one.

A dataset folder holds ``left_KK.png`` / ``right_KK.png``, the specimen file itself (the file, and a ``.pvd``'s VTU files: the
folder is self-contained), ``truth.json`` (cameras, placement, states, paint, masks), ``truth_left.npz`` and
``truth_right.npz`` (every pixel of that camera's reference image: the face seen, its ``(s, t)``, the mask bits of
:data:`scenes.specimens.mesh_specimen.MASK_BITS`) and ``truth_states.npz`` (on every ``truth_step_px``-th pixel of the left
reference image: the material point's displacement in the world frame, its image in both cameras and its exact
surface strain per state). :func:`load_specimen_truth` reads it back and computes the truth at any pixel.
"""
from __future__ import annotations

import json
import shutil
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from labio.atomic import atomic_writer, atomic_write_text
from scenes.specimens.fe_files import read_specimen_file
from scenes.specimens.mesh_specimen import MASK_BITS, MeshSpecimen, PixelTruth, warn_if_aliased
from scenes.sensor.noise import SensorNoise
from scenes.surfaces.paint import Paint
from scenes.specimens.surface_mesh import SurfaceMesh
from workbench.manifest import complete_folder, prepare_folder
from workbench.rigs import get_rig
from workbench.scenario import optics_of

SIDES = ("left", "right")
KIND = "specimen"
#: Monte-Carlo noise (grey RMS) of the pixels left to Mitsuba when the scenario does not say.
DEFAULT_MC_TARGET_GREY = 0.3


class SpecimenOutOfViewError(ValueError):
    """A camera sees no measurable part of the specimen (the message names the camera)."""


def rig_of(scenario):
    """The true rig of a specimen scenario: the user's calibration file (``rig.calibration``) or the named rig."""
    from workbench.rigs import rig_from_calibration

    if scenario.rig.calibration:
        return rig_from_calibration(scenario.rig.calibration, scenario.rig.scale)
    return get_rig(scenario.rig.name, scenario.rig.scale)


def rotation_xyz_deg(angles_deg) -> np.ndarray:
    """Rotation about x, then y, then z (deg): ``Rz Ry Rx``."""
    ax, ay, az = np.radians(np.asarray(angles_deg, float))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def parse_field(text: str):
    """The ``field`` option: '' (find it), a name, or 'x,y,z' names."""
    text = (text or "").strip()
    if not text:
        return None
    parts = [p.strip() for p in text.split(",")]
    if len(parts) == 3:
        return tuple(parts)
    if len(parts) != 1:
        raise ValueError(f"specimen.field {text!r}: give one vector field or three comma-separated scalar fields")
    return parts[0]


@dataclass
class SpecimenTruth:
    """Everything needed to score a stereo-DIC run on a rendered specimen (module docstring).

    Attributes
    ----------
    specimen : MeshSpecimen, in the specimen frame
    specs : {"left"|"right": SensorSpec}; camera_poses: {side: (R_cam_from_world, t_cam_from_world_mm)}
    pose : (R_world_from_specimen, t_world_from_specimen_mm)
    labels : what each state is
    maps : {side: PixelTruth of that camera's reference image (face, st, mask)}
    files : per state {"left": name, "right": name}
    info : the rest of truth.json
    """

    specimen: MeshSpecimen
    specs: dict
    camera_poses: dict
    pose: tuple
    labels: list
    maps: dict = field(default_factory=dict)
    files: list = field(default_factory=list)
    info: dict = field(default_factory=dict)

    @property
    def cameras(self) -> dict:
        return {side: (self.specs[side], *self.camera_poses[side]) for side in SIDES}

    def project(self, side: str, X_world_mm) -> np.ndarray:
        from scenes.optics.projection import project_points

        if side not in SIDES:
            raise ValueError(f"camera must be 'left' or 'right', got {side!r}")
        return project_points(self.specs[side], *self.camera_poses[side], X_world_mm)

    def material_points(self, pixels_xy, side: str = "left") -> tuple[np.ndarray, np.ndarray]:
        """(face (N,), st (N, 2)) seen at pixels of ``side``'s reference image: the stored map at integer pixels,
        Newton along the pixel's own ray from the nearest pixel's point elsewhere; -1/NaN where the pixel is not
        measurable (any mask bit)."""
        from scenes.specimens.ray_surface import refine_on_surface
        from scenes.optics.projection import pixel_rays

        px = np.asarray(pixels_xy, float).reshape(-1, 2)
        m = self.maps[side]
        H, W = m.face.shape
        c = np.rint(px).astype(np.int64)
        inside = (c[:, 0] >= 0) & (c[:, 1] >= 0) & (c[:, 0] < W) & (c[:, 1] < H)
        face = np.full(len(px), -1, np.int64)
        st = np.full((len(px), 2), np.nan)
        ci = np.clip(c, 0, [W - 1, H - 1])
        ok = inside & (m.mask[ci[:, 1], ci[:, 0]] == 0)
        face[ok] = m.face[ci[ok, 1], ci[ok, 0]]
        st[ok] = m.st[ci[ok, 1], ci[ok, 0]]
        off = ok & np.any(px != c, axis=1)
        if off.any():
            o, d = pixel_rays(self.specs[side], *self.camera_poses[side], px[off])
            st1, _ = refine_on_surface(self.specimen.mesh, face[off], st[off], self.specimen.displacements_mm[0], o, d,
                                       *self.specimen.state_pose(0, *self.pose))
            st[off] = st1
            bad = np.flatnonzero(off)[~np.all(np.isfinite(st1), axis=1)]
            face[bad] = -1
        return face, st

    def points_of_interest(self, pixels_left_ref) -> tuple[np.ndarray, np.ndarray]:
        """Truth of DIC points at pixels of the left reference image.

        Returns
        -------
        X_specimen_mm : (N, 3) the material points in the undeformed specimen frame (NaN: not measurable)
        X_world_mm : (K, N, 3) their positions in every state, world (= left camera) frame; NaN where the point is
            not measurable or hidden in that state from either camera
        """
        face, st = self.material_points(pixels_left_ref, "left")
        ok = face >= 0
        n = len(face)
        X_spec = np.full((n, 3), np.nan)
        X_world = np.full((self.specimen.n_states, n, 3), np.nan)
        if ok.any():
            X_spec[ok] = self.specimen.mesh.positions(face[ok], st[ok])
            X, _, visible = self.specimen.follow(face[ok], st[ok], self.cameras, *self.pose)
            X[~visible] = np.nan
            X_world[:, ok] = X
        return X_spec, X_world

    def strain_truths(self, pixels_left_ref) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`strain_truth` of every state at once (the pixels' material points found once): E (S, N, 2, 2), Q
        (N, 3, 2)."""
        face, st = self.material_points(pixels_left_ref, "left")
        ok = face >= 0
        S, n = self.specimen.n_states, len(face)
        E = np.full((S, n, 2, 2), np.nan)
        Q = np.full((n, 3, 2), np.nan)
        if ok.any():
            for k in range(S):
                E[k, ok], Qs = self.specimen.surface_strain(face[ok], st[ok], k)
            Q[ok] = np.einsum("ij,njk->nik", self.specimen.state_pose(0, *self.pose)[0], Qs)
        return E, Q

    def strain_truth(self, pixels_left_ref, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Exact surface Green-Lagrange strain of state k relative to state 0 at left reference pixels: E (N, 2, 2) in
        the basis Q (N, 3, 2), world frame (NaN where not measurable)."""
        face, st = self.material_points(pixels_left_ref, "left")
        ok = face >= 0
        E = np.full((len(face), 2, 2), np.nan)
        Q = np.full((len(face), 3, 2), np.nan)
        if ok.any():
            E[ok], Qs = self.specimen.surface_strain(face[ok], st[ok], k)
            Q[ok] = np.einsum("ij,njk->nik", self.specimen.state_pose(0, *self.pose)[0], Qs)
        return E, Q


# ------------------------------------------------------------------------------------------------------------
def _placed_mesh(sf, cfg) -> tuple[SurfaceMesh, np.ndarray, dict]:
    """The file's mesh and displacements in the specimen frame (turned, origin moved; displacements turned)."""
    from scenes.specimens.fe_files import UNITS_MM

    P = sf.mesh.points_mm
    if cfg.origin_mm is None:
        lo, hi = P.min(axis=0), P.max(axis=0)
        origin = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    else:
        origin = np.asarray(cfg.origin_mm, float) * UNITS_MM[cfg.unit]
    R = rotation_xyz_deg(cfg.rotation_deg)
    if cfg.origin_mm is None and np.any(np.asarray(cfg.rotation_deg) != 0):
        # the default origin is taken after turning: the turned mesh's front (smallest z) faces the cameras
        Q = (P - P.mean(axis=0)) @ R.T
        lo, hi = Q.min(axis=0), Q.max(axis=0)
        origin_turned = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
        points = Q - origin_turned + np.asarray(cfg.offset_mm, float)
        origin = P.mean(axis=0) + R.T @ origin_turned
    else:
        points = (P - origin) @ R.T + np.asarray(cfg.offset_mm, float)
    mesh = SurfaceMesh(points, sf.mesh.faces, source=sf.source, parents=sf.mesh.parents,
                       parent_types=sf.mesh.parent_types)
    turned = False
    if sf.mesh.parents is None and mesh.mean_normal()[2] > 0:
        mesh, turned = mesh.flipped(), True        # an open surface (a shell, a 2-D model) faces the cameras (-z)
    U = sf.displacements_mm @ R.T if len(sf.displacements_mm) else np.zeros((1, len(P), 3))
    return mesh, U, {"origin_mm_file_frame": (origin / UNITS_MM[cfg.unit]).tolist(), "R_specimen_from_file": R.tolist(),
                     "open_surface_turned_to_the_cameras": turned}


@dataclass(frozen=True)
class BuiltSpecimen:
    """A scenario's specimen before cameras: the painted FE surface with its states, the state labels, its pose
    (R_world_from_specimen, t_world_from_specimen_mm), the pixel footprint at the working distance (mm), the file
    read, the placement record and the rigid moves."""

    specimen: MeshSpecimen
    labels: list
    pose: tuple
    footprint_mm: float
    source: object          # the SpecimenFile read
    placement: dict
    rigid: list


def build_specimen(scenario) -> BuiltSpecimen:
    """Read, place, paint the scenario's specimen and give its states (no cameras, no truth maps)."""
    from workbench.experiments.rigid_motion.scenes import specimen_reference_pose

    cfg = scenario.specimen
    if not cfg.mesh:
        raise ValueError("scenario.specimen.mesh: no specimen file given")
    rig = rig_of(scenario)
    R0, t0 = specimen_reference_pose(rig)
    footprint_mm = float(np.linalg.norm(t0)) / rig.left.fx
    sf = read_specimen_file(cfg.mesh, unit=cfg.unit, displacement=parse_field(cfg.field), steps=cfg.steps,
                            times=cfg.times)
    mesh, U, placement = _placed_mesh(sf, cfg)
    labels = ([f"step {int(i)} (t = {t:g})" for i, t in zip(sf.step_indices, sf.times)] if len(sf.step_indices)
              else ["undeformed"])
    rigid = [(np.eye(3), np.zeros(3))] * len(U)
    for j in range(1, cfg.rigid_states + 1):
        rigid.append((rotation_xyz_deg(np.asarray(cfg.rigid_step_deg) * j), np.asarray(cfg.rigid_step_mm) * j))
        labels.append(f"rigid move {j}")
    U = np.concatenate([U, np.repeat(U[-1:], cfg.rigid_states, axis=0)])
    if cfg.static_pair:
        # The reference scene again with new sensor noise, moved by a sub-pixel offset in its plane: a repeat of the
        # same position samples the same paint points, and its floor would hide every error of a rendered motion.
        U = np.concatenate([U, U[:1]])
        dx, dy = (float(v) for v in cfg.static_offset_px)
        rigid.append((np.eye(3), np.array([dx, dy, 0.0]) * footprint_mm))
        labels.append(f"static: state 0 moved by ({dx:g}, {dy:g}) px in its plane, new noise")
    speckle_px = 5.0 if scenario.speckle.size_px is None else scenario.speckle.size_px
    speckle_mm = cfg.speckle_mm if cfg.speckle_mm is not None else speckle_px * footprint_mm
    edge_mm = None if scenario.speckle.edge_px is None else scenario.speckle.edge_px * footprint_mm
    texel_mm = cfg.texel_mm
    if texel_mm is None and edge_mm is not None:
        texel_mm = min(speckle_mm / 5.0, 2.0 * edge_mm)        # a sharp edge needs samples as fine as itself
    paint = Paint(kind=cfg.paint, method=cfg.paint_method, speckle_mm=speckle_mm, edge_mm=edge_mm,
                  texel_mm=texel_mm, density=scenario.speckle.density, contrast=0.8 * scenario.speckle.contrast,
                  checker_mm=cfg.checker_mm, direction=tuple(cfg.paint_direction), axis_point_mm=cfg.axis_point_mm,
                  axis_direction=cfg.axis_direction, max_angle_deg=cfg.max_paint_angle_deg, base_grey=cfg.base_grey,
                  seed=scenario.seed)
    specimen = MeshSpecimen(mesh, U, paint, sagitta_mm=cfg.sagitta_px * footprint_mm, rigid_poses=rigid)
    return BuiltSpecimen(specimen, labels, (R0, t0), footprint_mm, sf, placement, rigid)


def specimen_truth(scenario, *, progress: bool = False) -> SpecimenTruth:
    """Set up the scene of a ``specimen`` scenario (no rendering): read, place and paint the specimen, the cameras,
    and the per-pixel truth of both reference images. Raises :class:`SpecimenOutOfViewError` naming the camera
    that sees nothing measurable."""
    from workbench.experiments.bending.scenes import bending_specs

    cfg = scenario.specimen
    built = build_specimen(scenario)
    specimen, sf, (R0, t0), paint = built.specimen, built.source, built.pose, built.specimen.paint
    rig = rig_of(scenario)
    labels, placement, rigid, footprint_mm = built.labels, built.placement, built.rigid, built.footprint_mm
    specs = bending_specs(rig, scenario.rig.lens, t0, scenario.rig.f_number)
    truth = SpecimenTruth(specimen, specs, {side: rig.pose(side) for side in SIDES}, (R0, t0), labels)
    for side in SIDES:
        warn_if_aliased(paint, specs[side], float(np.linalg.norm(t0 - (-rig.pose(side)[0].T @ rig.pose(side)[1]))),
                        f"{sf.source} in the {side} camera")
    for side in SIDES:
        spec, Rc, tc = truth.cameras[side]
        pt = specimen.pixel_truth(truth.cameras, R0, t0, reference_side=side, grazing_limit_deg=cfg.grazing_limit_deg)
        measurable = int(np.sum(pt.mask == 0))
        if measurable == 0:
            seen = int(np.sum(pt.face >= 0))
            raise SpecimenOutOfViewError(
                f"{sf.source}: the {side} camera sees no measurable point of the specimen ({seen} pixels see its "
                f"surface; masks: {_mask_counts(pt.mask)}); check origin_mm, rotation_deg, offset_mm and the paint")
        truth.maps[side] = pt
    truth.info = {"lens": scenario.rig.lens, "placement": placement, "paint": paint.to_dict(),
                  "paint_layout": specimen.layout.summary(), "pieces_per_face_edge": specimen.tessellation.n,
                  "sagitta_mm": specimen.tessellation.max_sagitta_mm, "footprint_mm": footprint_mm,
                  "file": {"name": Path(sf.source).name, "unit": sf.unit, "field": sf.field_name,
                           "steps": [int(i) for i in sf.step_indices], "times": [float(t) for t in sf.times],
                           **sf.info},
                  "rigid_states": [{"R": np.asarray(R).tolist(), "t_mm": np.asarray(t).tolist()} for R, t in rigid],
                  "masks": {side: _mask_counts(truth.maps[side].mask) for side in SIDES},
                  "grazing_limit_deg": cfg.grazing_limit_deg}
    return truth


def _mask_counts(mask: np.ndarray) -> dict:
    out = {"measurable": int(np.sum(mask == 0))}
    out.update({name: int(np.sum(mask & bit > 0)) for name, bit in MASK_BITS.items()})
    return out


# ------------------------------------------------------------------------------------------------------------
def render_specimen(scenario, out_dir, *, progress: bool = True, overwrite: bool = False) -> SpecimenTruth:
    """Render every state of a ``specimen`` scenario in both cameras with its truth (module docstring); the
    folder gets its manifest last (complete or absent)."""
    from workbench.experiments.rigid_motion.scenes import render_info, render_stereo_states

    out_dir = Path(out_dir)
    truth = specimen_truth(scenario, progress=progress)
    K = truth.specimen.n_states
    digits = max(2, len(str(K - 1)))
    from scenes.specimens.fe_files import specimen_file_set

    src = Path(scenario.specimen.mesh)
    sources = specimen_file_set(src)              # a .pvd collection: its VTU files too
    if scenario.rig.calibration:                  # the user's rig travels with the dataset
        sources.append(Path(scenario.rig.calibration))
    copied = src.name
    images = [f"{side}_{k:0{digits}d}.png" for k in range(K) for side in SIDES]
    own = ["truth.json", "truth_left.npz", "truth_right.npz", "truth_states.npz"]
    clash = sorted({p.name for p in sources} & set(images + own + ["manifest.json"]))
    if clash:
        raise ValueError(f"{src}: the specimen file name {clash[0]} is one the dataset writes itself; rename it")
    planned = images + own + [p.name for p in sources]
    prepare_folder(out_dir, KIND, planned, overwrite=overwrite)
    r = scenario.render
    noise = SensorNoise(read_noise_grey=r.read_noise_grey, bit_depth=8, electrons_per_grey=r.electrons_per_grey)
    rig = rig_of(scenario)
    optics = optics_of(scenario, rig.pixel_pitch_mm)
    render_log: list = []
    mc_log: list = []
    # what the deterministic renderer cannot make (occluding edges, blur) is traced to this Monte-Carlo noise
    mc_target = (DEFAULT_MC_TARGET_GREY if r.mc_target_grey is None else r.mc_target_grey) \
        if r.speckle_renderer == "auto" else None
    truth.files = render_stereo_states(
        truth, lambda k: truth.specimen.surfaces(k, *truth.pose), K, out_dir, noise, spp=r.spp, seed=scenario.seed,
        desc=f"rendering {src.name}", progress=progress, renderer=r.speckle_renderer, render_log=render_log,
        mc_log=mc_log, mc_target_grey=mc_target, optics=optics, supersample=r.supersample, noise_seed=r.noise_seed)
    truth.info.update(render_info(rig, scenario.rig.scale, r.spp, scenario.seed, r.read_noise_grey, mc_target, mc_log,
                                  render_log, optics))
    for path in sources:
        with atomic_writer(out_dir / path.name, "wb") as handle, open(path, "rb") as source:
            shutil.copyfileobj(source, handle)
    for side in SIDES:
        m = truth.maps[side]
        _save_npz(out_dir / f"truth_{side}.npz", face=m.face.astype(np.int32), st=m.st, mask=m.mask)
    _save_npz(out_dir / "truth_states.npz", **_state_arrays(truth, scenario.specimen.truth_step_px))
    atomic_write_text(out_dir / "truth.json", json.dumps(_truth_to_json(truth, copied, scenario), indent=1))
    complete_folder(out_dir, KIND, [n for names in truth.files for n in names.values()] + planned[2 * K:],
                    {"rig": rig.name, "scale": scenario.rig.scale, "lens": scenario.rig.lens, "states": K,
                     "specimen": src.name})
    return truth


def _save_npz(path: Path, **arrays) -> None:
    with atomic_writer(path, "wb") as handle:
        np.savez_compressed(handle, **arrays)


def _state_arrays(truth: SpecimenTruth, step: int) -> dict:
    """Per-state truth on every ``step``-th pixel of the left reference image (float32; NaN: not measurable)."""
    m = truth.maps["left"]
    H, W = m.face.shape
    ys, xs = np.arange(0, H, step), np.arange(0, W, step)
    X, Y = np.meshgrid(xs, ys)
    pix = np.column_stack([X.ravel(), Y.ravel()]).astype(float)
    face, st = truth.material_points(pix)
    ok = face >= 0
    K = truth.specimen.n_states
    shape = (K, len(ys), len(xs))
    out = {"x_px": xs.astype(np.int32), "y_px": ys.astype(np.int32),
           "displacement_world_mm": np.full(shape + (3,), np.nan, np.float32),
           "xy_left_px": np.full(shape + (2,), np.nan, np.float32),
           "xy_right_px": np.full(shape + (2,), np.nan, np.float32),
           "strain_E11_E22_E12": np.full(shape + (3,), np.nan, np.float32),
           "strain_basis_world": np.full((len(ys), len(xs), 3, 2), np.nan, np.float32)}
    if not ok.any():
        return out
    Xw, xy, visible = truth.specimen.follow(face[ok], st[ok], truth.cameras, *truth.pose)
    flat = lambda a: a.reshape((K, -1) + a.shape[3:])  # noqa: E731
    for k in range(K):
        v = visible[k]
        idx = np.flatnonzero(ok)[v]
        flat(out["displacement_world_mm"])[k, idx] = (Xw[k] - Xw[0])[v]
        flat(out["xy_left_px"])[k, idx] = xy["left"][k][v]
        flat(out["xy_right_px"])[k, idx] = xy["right"][k][v]
        E, Q = truth.specimen.surface_strain(face[ok], st[ok], k)
        flat(out["strain_E11_E22_E12"])[k, idx] = np.column_stack([E[:, 0, 0], E[:, 1, 1], E[:, 0, 1]])[v]
    _, Q = truth.specimen.surface_strain(face[ok], st[ok], 0)
    out["strain_basis_world"].reshape(-1, 3, 2)[np.flatnonzero(ok)] = np.einsum(
        "ij,njk->nik", truth.specimen.state_pose(0, *truth.pose)[0], Q)
    return out


def _truth_to_json(truth: SpecimenTruth, copied: str, scenario) -> dict:
    from workbench.config import to_dict

    R, t = truth.pose
    return {
        "about": "Ground truth of a rendered specimen of one's own. World frame = left camera frame (OpenCV axes, mm). "
                 "The specimen file ('specimen_file') is placed by 'placement' (X_specimen = R_specimen_from_file "
                 "(X_file - origin) + offset, in mm) and X_world = R_world_from_specimen R_k (X + u_k(X)) + "
                 "R_world_from_specimen t_k + t_world_from_specimen_mm, u_k the FE displacement of state k and "
                 "(R_k, t_k) its rigid move ('rigid_states'). truth_<camera>.npz: per pixel of that camera's reference "
                 "image the face seen, its (s, t) and mask bits " + json.dumps(MASK_BITS) + " (0: measurable). "
                 "truth_states.npz: per state on a pixel grid of the left reference image, the displacement (world, "
                 "mm), the images in both cameras (px) and the surface Green-Lagrange strain (E11, E22, E12 in "
                 "strain_basis_world). workbench.experiments.specimen.scenes.load_specimen_truth computes the truth "
                 "at any pixel.",
        "scenario": to_dict(scenario),
        "specimen_file": copied,
        "cameras": {side: {"sensor_spec": truth.specs[side].to_dict(),
                           "R_cam_from_world": np.asarray(truth.camera_poses[side][0]).tolist(),
                           "t_cam_from_world_mm": np.asarray(truth.camera_poses[side][1]).tolist()} for side in SIDES},
        "R_world_from_specimen": np.asarray(R).tolist(), "t_world_from_specimen_mm": np.asarray(t).tolist(),
        "states": [{"index": k, "label": label, "files": truth.files[k] if truth.files else None}
                   for k, label in enumerate(truth.labels)],
        **truth.info,
    }


def load_specimen_truth(folder) -> SpecimenTruth:
    """Read a specimen dataset back (the specimen from its copied file and the scenario recorded in truth.json)."""
    from workbench import truth_schema as ts
    from workbench.config import from_dict
    from workbench.scenario import Scenario

    folder = Path(folder)
    doc = ts.read_truth(folder)
    specs, camera_poses = ts.cameras(doc)
    raw = json.loads((folder / "truth.json").read_text())
    scenario = from_dict(Scenario, raw["scenario"], "truth.json scenario")
    mesh_file = folder / raw["specimen_file"]
    from dataclasses import replace
    scenario = replace(scenario, specimen=replace(scenario.specimen, mesh=str(mesh_file)))
    if scenario.rig.calibration:                  # the copy in the dataset
        scenario = replace(scenario, rig=replace(scenario.rig,
                                                 calibration=str(folder / Path(scenario.rig.calibration).name)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")            # said when the dataset was made
        truth = _rebuild(scenario, specs, camera_poses)
    for side in SIDES:
        with np.load(folder / f"truth_{side}.npz") as z:
            truth.maps[side] = PixelTruth(z["face"].astype(np.int64), z["st"], z["mask"])
    truth.files = [ts.files(s) for s in ts.states(doc)]
    truth.labels = [s["label"] for s in raw["states"]]
    truth.info = {k: v for k, v in raw.items() if k not in ("cameras", "states", "scenario")}
    return truth


def _rebuild(scenario, specs, camera_poses) -> SpecimenTruth:
    """The specimen and pose of a scenario without the per-pixel maps (they are read from the dataset)."""
    built = build_specimen(scenario)
    return SpecimenTruth(built.specimen, specs, camera_poses, built.pose, built.labels)
