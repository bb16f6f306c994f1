"""The ``rigid_motion`` study case: the paper's calibration + rigid-motion test with every error source.

Two datasets, each rendered once per content in the store (:mod:`workbench.store`):

* ``checkerboard``: the calibration views of the (possibly imperfect) board through the (possibly imperfect)
  lenses, ``scenario.target`` (the paper: 30 views of 12 x 9 squares of 5 mm);
* ``rigid-motion``: the speckled beam on the stage, ``scenario.motion`` states (0 -> max in steps; the way
  back with ``return_to_zero``), with stage errors, camera drift and illumination changes.

The instrument calibrates from the board images alone (told the nominal square size; result stored under
the dataset, ``results/<hash>/calibration.json``) or uses the true rig, then measures every state and is
scored two ways: against the **stage reading** (what the paper could do: the mean of the measured
displacement magnitude D minus the nominal travel) and against the **truth** (the true displacement of every
material point, which differs from the reading when the stage errs).

Metrics per state (dimension ``stage_mm``, or ``state`` when the way back is measured):
``mean_error_um`` (mean D - stage reading, the paper's Fig 6a), ``std_um`` (std of D over the points, Fig 6b),
``mean_error_truth_um`` (mean of D - true |displacement|), ``points_fraction``; scalars
``reference_rms_um`` (reference shape against the truth after one rigid alignment), ``calibration_rms_px``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from scenes.sensor.drift import CameraDrift
from scenes.sensor.illumination import IlluminationChange
from scenes.deformation.stage import StageErrors
from scenes.sensor.noise import SensorNoise
from scenes.surfaces.checkerboard import Checkerboard
from workbench.rigs import get_rig
from workbench.scenario import Instrument, Scenario, dataset_parts, optics_of

METRICS = {"mean_error_um": "mean of measured D − stage reading (µm): the paper's Fig 6(a)",
           "std_um": "std of measured D over the points (µm): the paper's Fig 6(b)",
           "mean_error_truth_um": "mean of measured D − true displacement (µm)",
           "points_fraction": "fraction of points of interest measured",
           "reference_rms_um": "reference shape vs truth after one rigid alignment (µm RMS)",
           "calibration_rms_px": "calibration reprojection RMS, mean of the two cameras (px)",
           "triangulated_scale_error": "relative length error of the reference shape (least-squares scale vs truth)"}
FLOORS: dict = {}

#: The datasheet tilt the stepwise calibration starts from, per rig (as ``reproduce calibration``).
TILT_GUESS_DEG = {"paper": {"left": (0.0, -4.0), "right": (0.0, 4.0)},
                  "scheimpflug": {"left": (0.0, 1.0), "right": (0.0, -1.0)}}


def check(scenario: Scenario, instrument: Instrument | None = None) -> None:
    """Refuse what this experiment cannot render (called for every case before a study starts)."""
    if scenario.rig.calibration:
        raise ValueError("scenario.rig.calibration: a rig from a calibration file is for specimen scenarios "
                         "(experiment = \"specimen\"); the rigid-motion test uses the named rigs")
    if scenario.render.bit_depth != 8:
        raise ValueError(f"scenario.render.bit_depth = {scenario.render.bit_depth}: the rigid-motion renders are "
                         "8-bit images")
    states_mm(scenario)


def lens_terms(scenario: Scenario) -> dict | None:
    """The true-lens terms the instrument does not model, or None when all are zero."""
    terms = {k: getattr(scenario.lens, k) for k in ("k3", "s1", "s2", "s3", "s4")}
    return terms if any(terms.values()) else None


def board_of(scenario: Scenario) -> Checkerboard:
    """The printed board as it really is (the instrument is told only ``square_mm``)."""
    t = scenario.target
    return Checkerboard(square_mm=t.square_mm, print_scale_error=t.print_scale_error, bow_sag_mm=t.bow_sag_mm,
                        bow_axis=t.bow_axis, corner_noise_mm=t.corner_noise_mm, corner_noise_seed=scenario.seed)


def _noise(scenario: Scenario) -> SensorNoise:
    r = scenario.render
    return SensorNoise(read_noise_grey=r.read_noise_grey, electrons_per_grey=r.electrons_per_grey,
                       bit_depth=r.bit_depth or 8)


def render_calibration_views(scenario: Scenario, folder: Path) -> None:
    """The board views of ``scenario.target`` through the true rig (pinhole chief rays), into ``folder``."""
    from workbench.experiments.calibration.views import board_outline_mm, write_checkerboard_dataset
    from workbench.poses import random_board_poses
    from workbench.rigs import get_rig

    rig = get_rig(scenario.rig.name, scenario.rig.scale)
    board = board_of(scenario)
    n = scenario.target.calibration_views
    poses = random_board_poses(rig, board_outline_mm(board), n, scenario.seed,
                               max_tilt_deg=scenario.target.max_tilt_deg)
    write_checkerboard_dataset(rig, folder, n, scenario.seed, spp=scenario.render.spp, board=board,
                               noise=_noise(scenario), progress=False, poses=poses, overwrite=True,
                               lens_terms=lens_terms(scenario), renderer=scenario.render.board_renderer)


def states_mm(scenario: Scenario) -> np.ndarray:
    """The stage readings of the scenario: out to ``max_mm`` (and back with ``return_to_zero``)."""
    from scenes.deformation.stage import stage_states_mm

    m = scenario.motion
    try:
        out_and_back = stage_states_mm(m.max_mm, m.step_mm)
    except ValueError as err:
        raise ValueError(f"scenario.motion.{err}") from None
    return out_and_back if m.return_to_zero else out_and_back[: len(out_and_back) // 2 + 1]


def render_states(scenario: Scenario, folder: Path) -> None:
    """The stage states with the scenario's stage errors, camera drift and illumination change."""
    from workbench.experiments.rigid_motion.scenes import render_rigid_motion

    m, d, il = scenario.motion, scenario.drift, scenario.illumination
    stage = StageErrors(scale_error=m.stage_scale_error, straightness_um=m.stage_straightness_um,
                        travel_mm=m.max_mm, axis_tilt_deg=m.stage_axis_tilt_deg,
                        rotation_urad_per_mm=m.stage_rotation_urad_per_mm)
    drift = CameraDrift(camera=d.camera, translation_um_per_state=d.translation_um_per_state,
                        rotation_urad_per_state=d.rotation_urad_per_state)
    light = IlluminationChange(gain_per_state=il.gain_per_state, offset_grey_per_state=il.offset_grey_per_state,
                               gradient_per_state=il.gradient_per_state)
    r = scenario.render
    specimen = specimen_of(scenario)
    render_rigid_motion(scenario.rig.name, folder, scale=scenario.rig.scale, lens=scenario.rig.lens, spp=r.spp,
                        seed=scenario.seed, noise_grey=r.read_noise_grey, states=states_mm(scenario),
                        f_number=scenario.rig.f_number, progress=False, overwrite=True, stage_errors=stage,
                        drift=drift, illumination=light, lens_terms=lens_terms(scenario),
                        electrons_per_grey=r.electrons_per_grey, specimen=specimen,
                        focus_offset_mm=scenario.rig.focus_offset_mm, renderer=r.speckle_renderer,
                        optics=optics_of(scenario, get_rig(scenario.rig.name, scenario.rig.scale).pixel_pitch_mm))


#: Painted speckle size when the scenario leaves it open, px at the working distance (as ``reproduce rigid-motion``).
DEFAULT_SPECKLE_PX = 5.0


def specimen_of(scenario: Scenario):
    """The speckled beam for the rig's resolution with the scenario's speckle size, density and contrast."""
    from scenes.specimens.beam import BendingSpecimen
    from workbench.experiments.rigid_motion.scenes import specimen_reference_pose
    from workbench.rigs import get_rig

    rig = get_rig(scenario.rig.name, scenario.rig.scale)
    _, t0 = specimen_reference_pose(rig)
    pixel_mm = float(np.linalg.norm(t0)) / rig.left.fx
    sp = scenario.speckle
    return BendingSpecimen.for_pixel_size(pixel_mm, speckle_px=DEFAULT_SPECKLE_PX if sp.size_px is None else sp.size_px,
                                          density=sp.density, contrast=0.8 * sp.contrast, seed=scenario.seed)


def calibrate(scenario: Scenario, instrument: Instrument, views: Path, store):
    """The instrument's rig: calibrated from the stored board views (once per dataset and model), or the true rig."""
    from measurement.calibration.detection import board_points_mm
    from measurement.calibration.images import detect_pairs
    from measurement.calibration.io import CalibratedRig, load_calibration, save_calibration
    from measurement.calibration.stepwise import calibrate_stereo
    from workbench.config import hash_of
    from workbench.rigs import get_rig

    if instrument.calibration == "true":
        rig = get_rig(scenario.rig.name, scenario.rig.scale)
        return CalibratedRig("rmm", rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm), None
    guess = TILT_GUESS_DEG[scenario.rig.name]
    refine = scenario.rig.scale >= 0.75
    settings = {"model": instrument.calibration_model, "tilt_guess_deg": guess, "refine_corners": refine,
                "square_mm": scenario.target.square_mm}

    def compute(folder: Path) -> None:
        truth = json.loads((views / "truth.json").read_text())
        files = {side: [views / im["file"] for im in truth["images"] if im["camera"] == side] for side in ("left", "right")}
        pairs = detect_pairs(files["left"], files["right"], progress=False, refine=refine)
        board_mm = board_points_mm((11, 8), scenario.target.square_mm)     # the NOMINAL board: all the instrument knows
        cal = calibrate_stereo(pairs.points_left, pairs.points_right, board_mm, pairs.image_size,
                               model=instrument.calibration_model, tilt_guess_left_deg=guess["left"],
                               tilt_guess_right_deg=guess["right"])
        save_calibration(cal, folder / "calibration.json")
        from labio.atomic import atomic_write_text
        atomic_write_text(folder / "settings.json", json.dumps({**settings, "rms_px": dict(cal.rms_px),
                                                                "views_used": len(pairs.left_files)}, indent=1))

    folder, _ = store.result(views, hash_of(settings), compute, "calibration.json")
    rms = json.loads((folder / "settings.json").read_text())["rms_px"]
    return load_calibration(folder / "calibration.json"), float(np.mean(list(rms.values())))


def run(scenario: Scenario, instrument: Instrument, store) -> dict:
    """Study entry point: render (or reuse) both datasets, calibrate (or reuse), measure, score."""
    from workbench.experiments.rigid_motion.run import measure_rigid_motion
    from workbench.experiments.rigid_motion.scenes import load_truth

    parts = dataset_parts(scenario)
    reused = {}
    views = None
    if instrument.calibration == "rendered":
        key, content = parts["calibration"]
        views, reused["calibration"] = store.ensure("checkerboard", key, content,
                                                    lambda f: render_calibration_views(scenario, f))
    key, content = parts["states"]
    images, reused["states"] = store.ensure("rigid-motion", key, content, lambda f: render_states(scenario, f))
    rig, cal_rms = calibrate(scenario, instrument, views, store)
    truth = load_truth(images)
    m = measure_rigid_motion(truth, images, rig, subset_size=instrument.subset_px, step=instrument.step_px,
                             order=instrument.shape_order, interpolation=instrument.interpolation,
                             lowpass_sigma_px=instrument.prefilter_sigma_px, progress=False)
    rows = m["rows"]
    ref_pts, true_pts = m["shape"].X_mm[m["ok0"]], m["X_true_mm"][0][m["ok0"]]
    # the scale of the reconstruction: least-squares ratio of the spread of the measured points to the truth's
    spread = lambda X: np.sqrt(np.mean(np.sum((X - X.mean(0)) ** 2, axis=1)))  # noqa: E731
    scale_error = float(spread(ref_pts) / spread(true_pts) - 1.0)

    def per_state(key_fn):
        return [float(key_fn(r)) if "error" not in r else float("nan") for r in rows]

    stage = [r["imposed_mm"] for r in rows]
    dim = "state" if scenario.motion.return_to_zero else "stage_mm"
    coords = list(range(1, len(rows) + 1)) if dim == "state" else stage
    metrics = {"mean_error_um": per_state(lambda r: 1e3 * (r["mean_D_mm"] - abs(r["imposed_mm"]))),
               "std_um": per_state(lambda r: r["std_D_um"]),
               "mean_error_truth_um": per_state(lambda r: r["mean_error_um"]),
               "points_fraction": per_state(lambda r: r["points"] / r["points_total"]),
               "reference_rms_um": float(np.sqrt(np.mean(m["aligned_um"] ** 2))),
               "calibration_rms_px": float("nan") if cal_rms is None else cal_rms,
               "triangulated_scale_error": scale_error}
    vector = ("mean_error_um", "std_um", "mean_error_truth_um", "points_fraction")
    return {"metrics": metrics, "dims": {k: [dim] for k in vector}, "coords": {dim: coords}, "reused": reused}
