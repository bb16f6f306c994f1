"""The paper's rigid-motion test, truth side: a speckled bending beam on a vertical stage, rendered in stereo.

The beam (:class:`scenes.specimens.beam.BendingSpecimen`) stands with its front-face centre at the point where the
rig's optical axes meet (~376 mm in front of the left camera), its face normal along the bisector of the two
cameras, its length horizontal (perpendicular to world y). The stage moves it up in the left image (-y of
the left camera frame, :data:`scenes.deformation.stage.STAGE_UP_WORLD`) 0 -> 10 -> 0 mm in 1 mm steps; both cameras
render every state (8 bit, read noise sigma = 1 grey level by default) and ``truth.json`` records the
specimen, its pose in every state and the cameras as rendered.

Truth of a DIC point (DESIGN): the chief ray of the left reference pixel hits the specimen in state 0 at the
material point X0; its true position in state k is ``R_k X0 + t_k`` in the world (= left camera) frame:
:meth:`RigidMotionTruth.points_of_interest`.

Lens: ``"pinhole"`` or ``"thin"``. The thin lens keeps each camera's Scheimpflug-tilted sensor from the rig
and gets the focal length that focuses the face centre (:func:`scenes.optics.projection.focal_length_for_focus_mm`), at
``f_number`` (f/8 by default). Note that Table 1's tilts (beta ~ -/+4.5 deg) at this image distance
(37.6 mm) turn the plane of sharp focus ~50 deg away from a face looking along the bisector, so the face is
sharp only near its centre line; ``truth.json`` records the largest defocus blur per camera.
"""
from __future__ import annotations

import dataclasses
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from labio.atomic import atomic_write_image, atomic_write_text

from scenes.optics.camera import SensorSpec
from scenes.sensor.drift import CameraDrift, drifted_pose
from scenes.sensor.illumination import IlluminationChange
from scenes.deformation.stage import STAGE_UP_WORLD, StageErrors, stage_direction, stage_poses, stage_states_mm
from scenes.sensor.noise import SensorNoise, to_image_dtype
from scenes.optics.mtf import Optics
from scenes.rendering.mitsuba import render_view
from scenes.specimens.beam import BendingSpecimen
from scenes.optics.projection import (defocus_blur_px, focal_length_for_focus_mm, in_focus_points_world_mm,
                                      points_of_interest_truth, project_points)
from workbench.experiments.calibration.views import EXPOSURE_GREY, sensor_spec_for
from workbench.manifest import complete_folder, prepare_folder
from workbench.rigs import StereoRig, facing_plane_world, get_rig

SIDES = ("left", "right")
LENSES = ("thin", "pinhole")
#: Default f-number of the thin lens (modest aperture, as in DIC practice).
DEFAULT_F_NUMBER = 8.0
#: A warning is issued when the thin lens blurs part of the visible face by more than this (px).
BLUR_WARNING_PX = 3.0
#: In-view checks keep this many pixels from the image border.
MARGIN_PX = 2.0


class SpecimenOutOfViewError(ValueError):
    """The specimen's face is not (fully across its height) seen by a camera in some state."""


@dataclass
class RigidMotionTruth:
    """Everything needed to score a stereo-DIC run on the rendered rigid-motion images.

    Attributes
    ----------
    specimen : BendingSpecimen
    specs : {"left"|"right": SensorSpec}, the cameras exactly as rendered (lens included)
    camera_poses : {"left"|"right": (R_cam_from_world (3, 3), t_cam_from_world_mm (3,))}; world = left camera
    states_mm : (K,) stage positions, mm
    stage_direction_world : (3,) unit stage axis, world frame ((0, -1, 0): up in the left image)
    poses : K ``(R_world_from_specimen (3, 3), t_world_from_specimen_mm (3,))``
    files : K ``{"left": name, "right": name}`` relative to ``out_dir``
    info : the rest of truth.json (rig, lens, render settings, blur figures)
    """

    specimen: BendingSpecimen
    specs: dict[str, SensorSpec]
    camera_poses: dict[str, tuple[np.ndarray, np.ndarray]]
    states_mm: np.ndarray
    stage_direction_world: np.ndarray
    poses: list[tuple[np.ndarray, np.ndarray]]
    files: list[dict[str, str]] = field(default_factory=list)
    info: dict = field(default_factory=dict)

    @property
    def displacements_world_mm(self) -> np.ndarray:
        """True rigid displacement of every state relative to state 0, world (= left camera) frame, (K, 3)."""
        return np.array([t - self.poses[0][1] for _, t in self.poses])

    def points_of_interest(self, pixels_left_ref, reference_state: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Truth of DIC points defined at pixels of the LEFT image of ``reference_state``.

        Parameters
        ----------
        pixels_left_ref : (N, 2) float, px, OpenCV convention

        Returns
        -------
        X_specimen_mm : (N, 3) material points (NaN where the pixel does not see the front face)
        X_world_mm : (K, N, 3) their true positions in every state, world (= left camera) frame
        """
        return points_of_interest_truth(self.specs["left"], *self.camera_poses["left"], pixels_left_ref,
                                        self.specimen, self.poses, reference_state)

    def project(self, side: str, X_world_mm) -> np.ndarray:
        """Pixels (N, 2) where world points appear in camera ``side`` (chief ray, OpenCV convention)."""
        if side not in SIDES:
            raise ValueError(f"camera must be 'left' or 'right', got {side!r}")
        return project_points(self.specs[side], *self.camera_poses[side], X_world_mm)


# ------------------------------------------------------------------------------------------------------------
def specimen_reference_pose(rig: StereoRig, centre_world_mm=None) -> tuple[np.ndarray, np.ndarray]:
    """Pose ``X_world = R X_specimen + t`` of the beam at stage position 0.

    The front-face centre (specimen origin) sits at ``centre_world_mm`` (default: where the optical axes
    meet); the face normal (-z of the specimen) points to the midpoint of the two camera centres; the beam's
    length (specimen x) is perpendicular to world y, so its height (specimen y) is as close to world y
    (down in the left image) as the facing allows.
    """
    if centre_world_mm is None:
        centre, normal = facing_plane_world(rig)
    else:
        centre = np.asarray(centre_world_mm, float)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise ValueError(f"centre_world_mm must be a finite 3-vector, got {centre_world_mm!r}")
        normal = 0.5 * (rig.camera_centre_mm("left") + rig.camera_centre_mm("right")) - centre
    z_spec = -normal / np.linalg.norm(normal)     # into the material, away from the cameras
    x_spec = np.cross([0.0, 1.0, 0.0], z_spec)
    x_spec /= np.linalg.norm(x_spec)
    y_spec = np.cross(z_spec, x_spec)
    return np.stack([x_spec, y_spec, z_spec], axis=1), centre


def rigid_motion_specs(rig: StereoRig, lens: str, f_number: float, focus_world_mm) -> dict[str, SensorSpec]:
    """The two cameras as rendered: the rig's (tilted) cameras, thin lens focused on ``focus_world_mm``."""
    if lens not in LENSES:
        raise ValueError(f"lens must be one of {LENSES}, got {lens!r}")
    specs = {}
    for side in SIDES:
        spec = sensor_spec_for(rig, side)
        if lens == "thin":
            if not (np.isfinite(f_number) and f_number > 0):
                raise ValueError(f"f_number must be positive, got {f_number}")
            F = focal_length_for_focus_mm(spec, *rig.pose(side), np.asarray(focus_world_mm, float))
            spec = spec.with_(lens="thin", focal_length_mm=float(F), f_number=float(f_number))
        specs[side] = spec
    return specs


def check_specimen_in_view(specimen: BendingSpecimen, poses, specs: dict[str, SensorSpec], rig: StereoRig,
                           margin_px: float = MARGIN_PX) -> None:
    """Raise :class:`SpecimenOutOfViewError` naming camera and state unless both cameras see the face.

    The face must be seen from its front and its vertical centre line (x = 0, top to bottom edge) must lie
    inside both images in every state: the beam may be longer than the view, but its full height must be
    visible for the DIC region of interest.
    """
    H = 0.5 * specimen.height_mm
    centre_line = np.array([[0.0, -H, 0.0], [0.0, 0.0, 0.0], [0.0, H, 0.0]])
    for k, (R, t) in enumerate(poses):
        for side in SIDES:
            spec, (R_cw, t_cw) = specs[side], rig.pose(side)
            camera_in_specimen = R.T @ (-R_cw.T @ t_cw - t)
            if camera_in_specimen[2] >= 0:
                raise SpecimenOutOfViewError(f"the {side} camera sees the back of the specimen's front face in "
                                             f"state {k}")
            uv = project_points(spec, R_cw, t_cw, centre_line @ R.T + t)
            inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= margin_px - 0.5) \
                & (uv[:, 1] >= margin_px - 0.5) & (uv[:, 0] <= spec.width - 0.5 - margin_px) \
                & (uv[:, 1] <= spec.height - 0.5 - margin_px)
            if not np.all(inside):
                worst = uv[~inside][0]
                raise SpecimenOutOfViewError(
                    f"the specimen's front face leaves the {side} image ({spec.width} x {spec.height} px) in state "
                    f"{k}: its centre line reaches ({worst[0]:.1f}, {worst[1]:.1f}) px")


def face_blur_px(specimen: BendingSpecimen, pose, spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm,
                 n: int = 41) -> float:
    """Largest thin-lens defocus blur (px) over the part of the front face visible in the image."""
    R, t = pose
    gx, gy = np.meshgrid(np.linspace(-0.5, 0.5, n) * specimen.length_mm, np.linspace(-0.5, 0.5, n) * specimen.height_mm)
    X = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1) @ np.asarray(R).T + t
    uv = project_points(spec, R_cam_from_world, t_cam_from_world_mm, X)
    inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= spec.width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= spec.height - 0.5)
    return float(np.max(defocus_blur_px(spec, R_cam_from_world, t_cam_from_world_mm, X[inside]), initial=0.0))


def focus_plane_angle_deg(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, face_normal_world) -> float:
    """Angle between the thin lens' plane of sharp focus (fitted over the image) and the face (deg)."""
    u = np.linspace(0, spec.width - 1, 5)
    v = np.linspace(0, spec.height - 1, 5)
    pix = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
    X = in_focus_points_world_mm(spec, R_cam_from_world, t_cam_from_world_mm, pix)
    normal = np.linalg.svd(X - X.mean(0))[2][-1]     # distortion makes it a near-plane: least squares
    return float(np.degrees(np.arccos(min(1.0, abs(normal @ face_normal_world)))))


# ------------------------------------------------------------------------------------------------------------
def rigid_motion_truth(rig: StereoRig, *, lens: str = "thin", f_number: float = DEFAULT_F_NUMBER,
                       states_mm=None, specimen: BendingSpecimen | None = None, centre_world_mm=None,
                       direction_world=STAGE_UP_WORLD, seed: int = 0, stage_errors: StageErrors | None = None,
                       lens_terms: dict | None = None, focus_offset_mm: float = 0.0) -> RigidMotionTruth:
    """Set up the scene (no rendering): specimen, poses of every state, cameras; checks the view.

    ``specimen`` defaults to :meth:`BendingSpecimen.for_pixel_size` at the left camera's pixel footprint at
    the working distance (5 px speckles at any ``scale``), with speckle seed ``seed``. ``stage_errors``: the
    stage really moves the specimen by :func:`scenes.deformation.stage.true_stage_displacements_mm` (``states_mm`` stay
    the stage's readings). ``lens_terms``: distortion terms of the true lenses the rig's model lacks
    (``k3``, ``s1``-``s4`` of :class:`scenes.optics.camera.SensorSpec`). ``focus_offset_mm``: a thin lens is focused
    this far beyond the face centre along the left camera's line of sight (a focusing error).
    """
    states = stage_states_mm() if states_mm is None else np.asarray(states_mm, dtype=float).reshape(-1)
    if states.size == 0 or not np.all(np.isfinite(states)):
        raise ValueError("states_mm must be a non-empty list of finite stage positions (mm)")
    R0, t0 = specimen_reference_pose(rig, centre_world_mm)
    if specimen is None:
        pixel_mm = float(np.linalg.norm(t0)) / rig.left.fx
        specimen = BendingSpecimen.for_pixel_size(pixel_mm, seed=seed)
    poses = stage_poses(R0, t0, states, direction_world, errors=stage_errors)
    focus = t0 + float(focus_offset_mm) * t0 / np.linalg.norm(t0)
    specs = rigid_motion_specs(rig, lens, f_number, focus)
    if lens_terms:
        specs = {side: spec.with_(**lens_terms) for side, spec in specs.items()}
    check_specimen_in_view(specimen, poses, specs, rig)
    info: dict = {"lens": lens}
    if stage_errors is not None and not stage_errors.is_zero:
        info["stage_errors"] = dataclasses.asdict(stage_errors)
    if lens_terms:
        info["true_lens_terms"] = {k: float(v) for k, v in lens_terms.items()}
    if focus_offset_mm:
        info["focus_offset_mm"] = float(focus_offset_mm)
    if lens == "thin":
        blur = {side: max(face_blur_px(specimen, pose, specs[side], *rig.pose(side)) for pose in poses)
                for side in SIDES}
        angle = {side: focus_plane_angle_deg(specs[side], *rig.pose(side), R0[:, 2]) for side in SIDES}
        info.update(f_number=float(f_number), max_defocus_blur_px=blur, focus_plane_to_face_deg=angle)
        worst = max(blur, key=blur.get)
        if blur[worst] > BLUR_WARNING_PX:
            warnings.warn(f"thin lens at f/{f_number:g}: the front face is blurred by up to {blur[worst]:.1f} px in "
                          f"the {worst} image (its plane of sharp focus is {angle[worst]:.0f} deg from the face)",
                          stacklevel=2)
    return RigidMotionTruth(specimen, specs, {side: rig.pose(side) for side in SIDES}, states,
                            stage_direction(direction_world), poses, [], info)


def render_rigid_motion(rig: StereoRig | str, out_dir, scale: float = 1.0, lens: str = "thin", spp: int = 64,
                        seed: int = 0, noise_grey: float = 1.0, states=None, *,
                        f_number: float = DEFAULT_F_NUMBER, specimen: BendingSpecimen | None = None,
                        centre_world_mm=None, progress: bool = True, overwrite: bool = False,
                        stage_errors: StageErrors | None = None, drift: CameraDrift | None = None,
                        illumination: IlluminationChange | None = None, lens_terms: dict | None = None,
                        electrons_per_grey: float | None = None, focus_offset_mm: float = 0.0,
                        mc_target_grey: float | None = None, renderer: str = "auto", optics=None) -> RigidMotionTruth:
    """Render the rigid-motion test in both cameras and write ``left_KK.png``, ``right_KK.png``, ``truth.json``
    and ``manifest.json`` (truth and manifest last: a folder with a manifest is complete).

    Parameters
    ----------
    rig : StereoRig or rig name ("paper")
        A name is built at ``scale``; a StereoRig already has its scale (then ``scale`` must stay 1).
    out_dir : directory to write into (created)
    lens : "thin" (Scheimpflug-tilted sensor, focused on the face centre, ``f_number``) or "pinhole"
    spp : samples per pixel of Mitsuba renders (unused with ``mc_target_grey``: adaptive renders at that
        Monte-Carlo noise, grey)
    renderer : "auto" (the deterministic renderer where the view allows it: a pinhole) or "mitsuba"
        (:func:`render_stereo_states`)
    seed : seeds the speckle (default specimen), the sampler and the noise; same seed -> same files
    noise_grey : read-noise sigma in grey levels (8-bit images)
    states : stage positions in mm (default 0 -> 10 -> 0 mm in 1 mm steps, 21 states)
    specimen : default :meth:`BendingSpecimen.for_pixel_size` for the rig's resolution
    centre_world_mm : where the front-face centre sits in state 0 (default: where the optical axes meet)
    overwrite : replace an earlier dataset in ``out_dir`` (deletes exactly the files its manifest lists); without
        it such a folder is refused (:class:`workbench.manifest.DatasetFolderError`)
    stage_errors, drift, illumination, lens_terms, electrons_per_grey : error sources (DESIGN §7), each off by
        default: the stage's own errors (:class:`scenes.deformation.stage.StageErrors`), a camera drifting between states
        (:class:`scenes.sensor.drift.CameraDrift`), an illumination change between states
        (:class:`scenes.sensor.illumination.IlluminationChange`), true-lens terms the rig's model lacks, shot noise.
    optics : :class:`scenes.optics.mtf.Optics`, optional
        The lens' diffraction (None: ideal optics, the images as rendered).

    Returns
    -------
    RigidMotionTruth (also written as ``truth.json``; read it back with :func:`load_truth`)
    """
    rig, rig_scale = resolve_rig(rig, scale)
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    noise = SensorNoise(read_noise_grey=noise_grey, electrons_per_grey=electrons_per_grey, bit_depth=8)
    truth = rigid_motion_truth(rig, lens=lens, f_number=f_number, states_mm=states, specimen=specimen,
                               centre_world_mm=centre_world_mm, seed=seed, stage_errors=stage_errors,
                               lens_terms=lens_terms, focus_offset_mm=focus_offset_mm)
    out_dir = Path(out_dir)
    digits = max(2, len(str(len(truth.poses) - 1)))
    planned = [f"{side}_{k:0{digits}d}.png" for k in range(len(truth.poses)) for side in SIDES]
    prepare_folder(out_dir, "rigid-motion", planned + ["truth.json"], overwrite=overwrite)
    texture = truth.specimen.texture()
    mc_log: list = []
    render_log: list = []
    files = render_stereo_states(truth, lambda k: truth.specimen.surfaces(*truth.poses[k], texture=texture),
                                 len(truth.poses), out_dir, noise, spp=spp, seed=seed,
                                 desc=f"rendering rigid motion ({lens})", progress=progress, drift=drift,
                                 illumination=illumination, mc_target_grey=mc_target_grey, mc_log=mc_log,
                                 renderer=renderer, render_log=render_log, optics=optics)
    truth.files = files
    truth.info.update(render_info(rig, rig_scale, spp, seed, noise_grey, mc_target_grey, mc_log, render_log,
                                  optics))
    if electrons_per_grey is not None:
        truth.info["render"]["electrons_per_grey"] = float(electrons_per_grey)
    if drift is not None and not drift.is_zero:
        truth.info["camera_drift"] = {**dataclasses.asdict(drift), "camera_poses_as_rendered": [
            {side: [np.asarray(a).tolist() for a in drifted_pose(*truth.camera_poses[side], drift, k, camera=side)]
             for side in SIDES} for k in range(len(truth.poses))]}
    if illumination is not None and not illumination.is_zero:
        truth.info["illumination_change"] = dataclasses.asdict(illumination)
    atomic_write_text(out_dir / "truth.json", json.dumps(_truth_to_json(truth), indent=1))
    complete_folder(out_dir, "rigid-motion", [n for names in files for n in names.values()] + ["truth.json"],
                    {"rig": rig.name, "scale": rig_scale, "lens": lens, **truth.info["render"],
                     "states_mm": [float(v) for v in truth.states_mm]})
    return truth


def resolve_rig(rig: StereoRig | str, scale: float) -> tuple[StereoRig, float | None]:
    """A rig given by name is built at ``scale``; a StereoRig is already scaled (its scale is then unknown,
    None, and its intrinsics are recorded instead) and ``scale`` must stay 1."""
    if isinstance(rig, str):
        return get_rig(rig, scale), float(scale)
    if scale != 1.0:
        raise ValueError("scale applies to a rig given by name; a StereoRig is already scaled (get_rig(name, scale))")
    return rig, None


#: Renderers of speckle states: "auto" (the deterministic renderer, :mod:`scenes.rendering.exact`, where a view
#: allows it: a pinhole, or a thin lens' in-focus pixels with adaptive Mitsuba for the rest; Mitsuba otherwise),
#: "mitsuba" (Monte Carlo: fixed spp or adaptive).
SPECKLE_RENDERERS = ("auto", "mitsuba")


def paper_optics(rig: StereoRig, f_number: float = DEFAULT_F_NUMBER):
    """The lens' diffraction of the paper's experiments (:class:`scenes.optics.mtf.Optics`): f/8, 550 nm, the rig's
    pixels."""
    return Optics(f_number=f_number, pixel_pitch_mm=rig.pixel_pitch_mm)


def speckle_render_content(renderer: str, lens: str, mc_target_grey: float | None = None) -> dict:
    """How the speckle renderer enters a stored dataset's content hash: nothing where every image is Mitsuba's
    (``"mitsuba"``, or a thin lens at a fixed spp, which ``"auto"`` leaves to Mitsuba), so those datasets keep
    their hashes."""
    from workbench.scenario import SPECKLE_RENDERER_TAGS

    if renderer not in SPECKLE_RENDERERS:
        raise ValueError(f"speckle renderer {renderer!r}: choose one of {', '.join(SPECKLE_RENDERERS)}")
    if renderer == "mitsuba" or (lens != "pinhole" and mc_target_grey is None):
        return {}
    return {"speckle_renderer": SPECKLE_RENDERER_TAGS[renderer]}


def render_stereo_states(truth, surfaces_of_state, n_states: int, out_dir: Path, noise: SensorNoise, *, spp: int,
                         seed: int, desc: str, progress: bool = True, drift: CameraDrift | None = None,
                         illumination: IlluminationChange | None = None, mc_target_grey: float | None = None,
                         mc_log: list | None = None, renderer: str = "auto",
                         render_log: list | None = None, optics=None, supersample: int = 1,
                         noise_seed: int | None = None) -> list[dict[str, str]]:
    """Render every state in both cameras as 8-bit ``left_KK.png`` / ``right_KK.png`` (atomic writes).

    ``truth`` provides ``specs`` and ``camera_poses``; ``surfaces_of_state(k)`` the scene of state k. One seed per
    image (``seed * 100003 + 2 k + camera``): Monte-Carlo noise is pixel-locked, so states must not share it.
    ``drift``: the drifting camera renders state k from :func:`scenes.sensor.drift.drifted_pose`; ``illumination``:
    the scene radiance of state k changes (:meth:`scenes.sensor.illumination.IlluminationChange.apply`) before the
    sensor noise. ``renderer`` (:data:`SPECKLE_RENDERERS`): ``"auto"`` renders both cameras of a state with
    :func:`scenes.rendering.exact.render_view_exact` (exact coverage, Gauss-Legendre quadrature of the speckle: no
    Monte-Carlo noise) where it can (a pinhole, no occlusion); with ``mc_target_grey`` also through a thin lens,
    whose in-focus pixels it makes and whose blurred rest Mitsuba's adaptive renderer traces
    (:func:`scenes.rendering.adaptive.render_views_auto`). Mitsuba renders at ``spp``, or, with ``mc_target_grey``, both
    cameras of a state from one scene with :mod:`scenes.rendering.adaptive` at that Monte-Carlo noise; each such image's
    measured noise and sample counts are appended to ``mc_log``. ``render_log`` gets one entry per image: which
    renderer made it (with the share of pixels made without Monte Carlo), and why Mitsuba did where ``"auto"``
    fell back. ``optics`` (:class:`scenes.optics.mtf.Optics`): the lens' diffraction on every render, before the
    illumination change and the sensor; ``supersample``: every view is rendered that many times finer along each
    axis (:meth:`scenes.optics.camera.SensorSpec.supersampled`) and brought back through ``optics`` (binned). Returns the
    file names per state.
    """
    from scenes.rendering.exact import RENDERER_OCCLUSION
    from scenes.rendering.render import render_views

    if renderer not in SPECKLE_RENDERERS:
        raise ValueError(f"speckle renderer {renderer!r}: choose one of {', '.join(SPECKLE_RENDERERS)}")
    digits = max(2, len(str(n_states - 1)))
    files = []
    for k in tqdm(range(n_states), desc=desc, disable=not progress):
        surfaces = surfaces_of_state(k)
        names = {}
        poses = {side: drifted_pose(*truth.camera_poses[side], drift, k, camera=side) for side in SIDES}
        views = [(truth.specs[side].supersampled(supersample), poses[side]) for side in SIDES]
        made = render_views(views, surfaces, renderer=renderer, spp=spp, seed=seed * 100003 + 2 * k,
                            exposure_grey=EXPOSURE_GREY[8], mc_target_grey=mc_target_grey)
        for c, side in enumerate(SIDES):
            image_seed = seed * 100003 + 2 * k + c
            view = made[c]
            rendered, made_by, mc, entry = view.image_grey, view.renderer, view.mc, {}
            if view.reason:
                entry["fallback"] = view.reason
            elif view.known_fraction is not None and (made_by == RENDERER_OCCLUSION or made_by.startswith("in-focus")):
                entry["known_fraction"] = round(view.known_fraction, 6)   # any thin-lens mix
            if mc is not None and mc_log is not None:
                mc_log.append({"state": k, "camera": side, **mc})
            if render_log is not None:
                render_log.append({"state": k, "camera": side, "renderer": made_by, **entry})
            if optics is not None or supersample > 1:
                rendered = (optics or Optics()).apply(rendered, supersample)
            image = rendered
            image = image if illumination is None else illumination.apply(image, k)
            # Reconstruction-filter and Monte-Carlo ringing can dip a dark pixel a little below 0; a sensor holds no
            # negative charge, and shot noise needs the exposure >= 0.
            image = np.maximum(image, 0.0)
            names[side] = f"{side}_{k:0{digits}d}.png"
            noise_image_seed = image_seed if noise_seed is None else noise_seed * 100003 + 2 * k + c
            atomic_write_image(out_dir / names[side], to_image_dtype(noise.apply(image, seed=noise_image_seed), 8))
        files.append(names)
    return files


def known_fraction_range(render_images: list[dict]) -> list[float] | None:
    """[min, max] share of pixels made without Monte Carlo over the thin-lens images of ``render_log`` entries
    (None when no image was made that way)."""
    shares = [float(r["known_fraction"]) for r in render_images if "known_fraction" in r]
    return [min(shares), max(shares)] if shares else None


def render_info(rig: StereoRig, rig_scale, spp: int, seed: int, noise_grey: float,
                mc_target_grey: float | None = None, mc_log: list | None = None,
                render_log: list | None = None, optics=None) -> dict:
    """The ``render`` and ``rig`` entries of a rendered sequence's truth.json (``renderers``: images per renderer,
    ``images``: which renderer made each image and why Mitsuba did where the deterministic one could not;
    ``optics``: the lens' diffraction, when there is one)."""
    adaptive = {} if mc_target_grey is None else {"mc_target_grey": float(mc_target_grey), "mc": mc_log or []}
    if optics is not None and not optics.ideal:
        adaptive["optics"] = optics.to_dict()
    if render_log:
        names = [r["renderer"] for r in render_log]
        adaptive.update(renderers={n: names.count(n) for n in sorted(set(names))}, images=render_log)
    return {"render": {"spp": "adaptive" if mc_target_grey is not None else int(spp), **adaptive, "seed": int(seed),
                       "bit_depth": 8, "read_noise_grey": float(noise_grey), "exposure_grey": EXPOSURE_GREY[8]},
            "rig": {"name": rig.name, "scale": rig_scale,
                    "R_right_from_left": np.asarray(rig.R_right_from_left).tolist(),
                    "T_right_from_left_mm": np.asarray(rig.T_right_from_left_mm).tolist(),
                    "pixel_pitch_mm": rig.pixel_pitch_mm,
                    "intrinsics": {side: rig.camera(side).to_dict() for side in SIDES}}}


# ------------------------------------------------------------------------------------------------------------
def _truth_to_json(truth: RigidMotionTruth) -> dict:
    R_rl = truth.camera_poses["right"][0]
    d_world = truth.displacements_world_mm
    return {
        "about": "Ground truth of the rendered rigid-motion test. World frame = left camera frame (OpenCV axes: x "
                 "right, y down, z forward; mm). Specimen pose per state: X_world = R_world_from_specimen @ "
                 "X_specimen + t_world_from_specimen_mm; specimen frame: origin at the front-face centre, x along "
                 "the length, y along the height, z into the material (the speckled face z = 0 looks at the "
                 "cameras). The stage moves the specimen along stage_direction_world = -y of the left camera "
                 "(up in the image). Cameras as rendered: X_cam = R_cam_from_world @ X_world + t; pixels OpenCV "
                 "(pixel centres at integer coordinates). Truth of a DIC point: the chief ray of the left "
                 "reference pixel hits the face in state 0 at X0 (material point); in state k it is at "
                 "R_k X0 + t_k (workbench.experiments.rigid_motion.scenes.load_truth(...).points_of_interest).",
        "specimen": {"type": "BendingSpecimen", **truth.specimen.to_dict()},
        "cameras": {side: {"sensor_spec": truth.specs[side].to_dict(),
                           "R_cam_from_world": np.asarray(truth.camera_poses[side][0]).tolist(),
                           "t_cam_from_world_mm": np.asarray(truth.camera_poses[side][1]).tolist()}
                    for side in SIDES},
        "stage_direction_world": truth.stage_direction_world.tolist(),
        "states": [{"index": k, "stage_mm": float(s), "files": truth.files[k] if truth.files else None,
                    "R_world_from_specimen": np.asarray(R).tolist(), "t_world_from_specimen_mm": np.asarray(t).tolist(),
                    "displacement_left_cam_mm": d_world[k].tolist(),
                    "displacement_right_cam_mm": (R_rl @ d_world[k]).tolist()}
                   for k, (s, (R, t)) in enumerate(zip(truth.states_mm, truth.poses, strict=True))],
        **truth.info,
    }


def load_truth(out_dir) -> RigidMotionTruth:
    """Read ``truth.json`` written by :func:`render_rigid_motion` back into a :class:`RigidMotionTruth`.

    Raises FileNotFoundError when there is no ``truth.json`` and :class:`labio.schema.FileFormatError`
    (a ValueError naming the file and the key) for anything malformed (:mod:`workbench.truth_schema`).
    """
    from workbench import truth_schema as ts

    doc = ts.read_truth(out_dir)
    specimen = ts.specimen(doc["specimen"])
    specs, camera_poses = ts.cameras(doc)
    direction = doc["stage_direction_world"]
    stage_direction_world = direction.vector(3, lo_norm=1 - 1e-6, hi_norm=1 + 1e-6)
    states = ts.states(doc)
    stage_mm = np.array([s["stage_mm"].number(-ts.MAX_MM, ts.MAX_MM, unit="mm") for s in states])
    poses = [(s["R_world_from_specimen"].rotation(), ts.position(s["t_world_from_specimen_mm"])) for s in states]
    files = [ts.files(s) for s in states]
    info = ts.info(doc, ("about", "specimen", "cameras", "stage_direction_world", "states"), LENSES)
    return RigidMotionTruth(specimen, specs, camera_poses, stage_mm, stage_direction_world, poses, files, info)
