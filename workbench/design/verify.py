"""A design checked by rendering it: the rig rendered with the specimen and measured by the instrument.

The designed rig is written as a calibration JSON with its optics (pixel pitch, thin lenses, f-number:
:func:`workbench.rigs.optics_block`) and rendered through the project's one specimen path
(:func:`workbench.experiments.specimen.scenes.render_specimen`: a ``specimen`` scenario whose ``rig.calibration``
is that file; a plane is a thin box written as STL, a catalog specimen its FE file) with the design's speckle,
noise-free: the reference state and one deformed state (the FE result's last step; a plane moves rigidly by a
fraction of a pixel in its plane and two pixels towards the cameras). The camera is then applied the way the design
assumed: the noise-free images are scaled to the design's exposure and each draw gets the camera's read and shot
noise and its quantisation (:func:`camera_image`). The instrument measures

* ``repeats`` **static pairs** (two noise draws of the reference scene; whatever it reports between them is
  noise, :func:`workbench.twin.measure.static_noise_stereo`, exactly as ``workbench stereo`` runs) -- measured:
  the standard deviation of each component over the ROI's points, pooled over repeats; beside it the instrument's
  own per-point sigma;
* the **deformed state** against the truth (random error: the standard deviation of the error, its mean removed).

U, V, W in the specimen frame (along the face's x, y and its normal), as the design predicts them on a ROI grid
:data:`VERIFY_DENSITY` times denser than the search's, its RMS where the measurement is (each measured point takes its
nearest sample's sigma: the ROI weighed as the measurement weighs it; where the match fails -- a grazing view at a
curved face's edge -- neither side counts, and the whole ROI's prediction is given beside). Where the design
was predicted at full resolution and the render is smaller (``verify.scale``), the prediction is redone for the
rendered camera (same geometry, tilts and paint; fewer, larger pixels).
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from measurement.calibration.io import CalibratedRig, save_rig
from measurement.dic import DICSettings
from measurement.image_io import read_grey
from measurement.speckle_quality import NoiseModel
from measurement.stereo_dic import measure_state

from ..rigs import optics_block
from ..twin.measure import static_noise_stereo
from .geometry import build_candidate
from .predict import exposure_grey, noise_variance_grey2, predict
from .surface import resampled

#: The verification predicts on a ROI grid this many times denser (per axis) than the search's.
VERIFY_DENSITY = 4
#: The plane specimen's thickness when written as a box, mm.
PLANE_THICKNESS_MM = 2.0
#: A plane's deformed state: a rigid move along the face's x, y and towards the cameras, in pixels at its centre.
PLANE_MOVE_PX = (0.37, 0.21, -2.0)


def write_rig_files(candidate, folder) -> dict:
    """The rig as this project's calibration JSON (with its optics) and OpenCV YAML; returns the paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rig = candidate.rig
    cal = CalibratedRig("rmm", rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
    extra = {**optics_block(rig.pixel_pitch_mm, rig.lens_focal_length_mm, rig.f_number),
             "design": {"label": rig.name, "camera": candidate.camera_name, "lens": candidate.lens_name,
                        "working_distance_mm": candidate.placement.distance_mm,
                        "stereo_angle_deg": candidate.placement.stereo_angle_deg,
                        "R_world_from_specimen": np.asarray(candidate.R_world_from_spec).tolist(),
                        "t_world_from_specimen_mm": np.asarray(candidate.t_world_from_spec_mm).tolist()}}
    paths = {"json": folder / "rig.json", "opencv_yaml": folder / "rig_opencv.yaml"}
    save_rig(cal, paths["json"], extra)
    save_rig(cal, paths["opencv_yaml"])
    return paths


def plane_file(width_mm: float, height_mm: float, folder) -> Path:
    """A thin box whose front face (z = 0, facing -z) is the plane, as STL."""
    import trimesh

    box = trimesh.creation.box(extents=(width_mm, height_mm, PLANE_THICKNESS_MM))
    box.apply_translation((0.0, 0.0, PLANE_THICKNESS_MM / 2))
    path = Path(folder) / "plane.stl"
    path.parent.mkdir(parents=True, exist_ok=True)
    box.export(path)
    return path


def camera_image(clean_grey: np.ndarray, gain: float, camera, seed: int) -> np.ndarray:
    """A noise-free image scaled by ``gain`` with the camera's read and shot noise, quantised to its bit depth."""
    from scenes.sensor.noise import apply_sensor_noise

    exposed = np.asarray(clean_grey, np.float64) * gain
    noisy = apply_sensor_noise(exposed, read_noise_grey=camera.read_noise_grey,
                               electrons_per_grey=camera.electrons_per_grey, bit_depth=None, seed=seed)
    return np.clip(np.round(noisy), 0, camera.full_scale_grey)


def camera_noise_model(camera) -> NoiseModel:
    """The camera's noise as the instrument takes it (read noise with quantisation, shot-noise gain)."""
    read = math.sqrt(camera.read_noise_grey ** 2 + 1.0 / 12.0)
    return NoiseModel(sigma_grey=read, read_noise_grey=read, electrons_per_grey=camera.electrons_per_grey,
                      source="design: camera data sheet")


def scenario_for(design, candidate, rig_json: Path, specimen_path: Path, speckle_mm: float, footprint_mm: float,
                 folder: Path):
    """The ``specimen`` scenario that renders the design (module notes)."""
    from workbench.config import from_dict
    from workbench.experiments.specimen.catalog import SCENARIO_EXTRAS
    from workbench.scenario import Scenario

    s = design.specimen
    spec = {"mesh": str(specimen_path), "speckle_mm": float(speckle_mm), "static_pair": False}
    if s.plane_mm is not None:
        spec.update(rigid_states=1, rigid_step_mm=[float(v * footprint_mm) for v in PLANE_MOVE_PX])
    else:
        spec.update(steps=[0, -1])
        if s.catalog:
            spec.update(SCENARIO_EXTRAS.get(s.catalog, {}))
        else:
            spec.update(unit=s.unit)
    doc = {"experiment": "specimen", "seed": int(design.seed),
           "rig": {"calibration": str(rig_json), "scale": float(design.verify.scale), "lens": "thin",
                   "f_number": float(candidate.rig.f_number), "wavelength_nm": float(design.search.wavelength_nm)},
           "render": {"read_noise_grey": 0.0, "mc_target_grey": float(design.verify.mc_target_grey)},
           "speckle": {"contrast": float(min(s.speckle_contrast / 0.8, 1.2))},
           "specimen": spec}
    return from_dict(Scenario, doc, "scenario")


def _roi_mask(truth, surface, shape, subset_px: int) -> np.ndarray:
    """Pixels of the left reference image whose face point lies in the design's ROI, measurable (truth mask)."""
    import cv2

    from workbench.experiments.specimen.case import measurable_mask

    R0, t0 = truth.pose
    spec, Rc, tc = truth.cameras["left"]
    from scenes.optics.projection import project_points
    edge = np.asarray(surface.points_mm)
    px = project_points(spec, Rc, tc, edge @ np.asarray(R0).T + np.asarray(t0))
    hull = cv2.convexHull(np.round(px[np.all(np.isfinite(px), axis=1)]).astype(np.int32))
    mask = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(mask, hull, 1)
    return (mask > 0) & measurable_mask(truth, subset_px)


def _spec_frame(values_world: np.ndarray, R_world_from_spec: np.ndarray) -> np.ndarray:
    """Rows of world vectors as specimen-frame vectors."""
    return values_world @ np.asarray(R_world_from_spec)


def _std(a) -> float:
    a = a[np.isfinite(a)]
    return float(np.std(a, ddof=1)) if a.size > 2 else math.nan


def _rms(a) -> float:
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if a.size else math.nan


def verify(design, prediction, surface, specimen_path: Path | None, folder, table, *, progress=None) -> dict:
    """Render and measure one designed rig (module notes); ``table`` is the search's pattern table. Returns
    predicted, measured and the instrument's sigma per component (µm), the settings and the file locations."""
    from workbench.experiments.specimen.scenes import render_specimen

    folder = Path(folder)
    cand = prediction.candidate
    s = design.specimen
    camera = next(c for c in design.camera if c.name == cand.camera_name)
    lens = next(ln for ln in design.lens if ln.name == cand.lens_name)
    files = write_rig_files(cand, folder)
    if specimen_path is None:
        specimen_path = plane_file(*s.plane_mm, folder / "specimen")
    speckle_mm = prediction.summary["speckle_mm"]
    scenario = scenario_for(design, cand, files["json"], specimen_path, speckle_mm,
                            prediction.summary["footprint_mm_per_px"] / design.verify.scale, folder)
    images = folder / "images"
    truth = render_specimen(scenario, images, progress=progress is not None, overwrite=True)

    # the prediction for the rendered camera (verify.scale) and the reference position (no depth travel)
    sc = design.verify.scale
    cam_r = replace(camera, width_px=int(round(camera.width_px * sc)), height_px=int(round(camera.height_px * sc)),
                    pixel_pitch_um=camera.pixel_pitch_um / sc)
    plane_c, plane_n = surface.best_plane()
    cand_r = build_candidate(cam_r, lens, cand.f_number, cand.placement.distance_mm,
                             cand.placement.stereo_angle_deg, tilt=cand.tilted,
                             tilt_max_deg=design.adapter.tilt_max_deg, plane_centre_mm=plane_c, plane_normal=plane_n)
    # on a grid VERIFY_DENSITY times denser than the search's: the measurement weighs the ROI by its points
    dense = resampled(s, specimen_path, tuple(VERIFY_DENSITY * (n - 1) + 1 for n in s.sample_points))
    pred_r = predict(cand_r, dense, cam_r, design.lighting, design.search, table, speckle_mm=speckle_mm,
                     depth_range_mm=0.0, contrast=s.speckle_contrast)

    # the camera: exposure and noise
    m = pred_r.summary["magnification"]
    E, _ = exposure_grey(camera, design.lighting, cand.f_number, m, s.speckle_contrast)
    gain = E / 255.0                                   # the renders' paint value 1 is 255 grey
    noise = camera_noise_model(camera)
    models = {"left": noise, "right": noise}
    settings = DICSettings(subset_size=design.search.subset_px, step=design.search.step_px, order=design.search.order)
    clean = {side: read_grey(images / truth.files[0][side]).astype(np.float64) for side in ("left", "right")}
    roi = _roi_mask(truth, surface, clean["left"].shape, design.search.subset_px)
    Rws = np.asarray(truth.pose[0])
    seed = int(design.seed) * 1009
    runs = []
    for r in range(design.verify.repeats):
        draw = {f"{side}{k}": camera_image(clean[side], gain, camera, seed + 4 * r + 2 * i + k)
                for i, side in enumerate(("left", "right")) for k in (0, 1)}
        sn = static_noise_stereo(truth_rig(scenario), draw["left0"], draw["right0"], draw["left1"], draw["right1"],
                                 settings, mask=roi, strain_window=design.search.strain_window, noise=models)
        values = _spec_frame(sn.values / 1e3, Rws) * 1e3            # µm, mean removed per component
        good = np.isfinite(values[:, 0])
        runs.append({"measured": [_std(values[:, k]) for k in range(3)], "points": int(good.sum()),
                     "strain_ue": sn.strain_ue, "instrument_left_frame_um": sn.instrument_sigma,
                     "measured_xy": np.column_stack([sn.x_px, sn.y_px])[good]})
        if progress is not None:
            progress(f"static pair {r + 1}/{design.verify.repeats}")
    measured = [float(np.sqrt(np.mean([run["measured"][k] ** 2 for run in runs]))) for k in range(3)]
    # the prediction where the measurement is: each measured point takes its nearest ROI sample's sigma (so the ROI
    # is weighed as the measurement weighs it, by image area); samples with no measured point within a grid step (a
    # match that failed there: a grazing view at a curved face's edge) count on neither side
    near = _nearest_samples(pred_r.pixels_left, runs[0]["measured_xy"])
    covered = _covered_samples(pred_r.pixels_left, runs[0]["measured_xy"], design.search.step_px)
    predicted = [_rms(pred_r.sigma_U_um[near, k]) for k in range(3)]
    out = {"label": cand.rig.name, "files": {k: str(v) for k, v in files.items()},
           "images": str(images), "scale": sc, "exposure_grey": E, "noise_grey": math.sqrt(noise_variance_grey2(
               camera, 0.5 * E)),
           "static": {"predicted_um": predicted, "measured_um": measured,
                      "predicted_whole_roi_um": [pred_r.summary[f"sigma_{c}_um"] for c in "UVW"],
                      "roi_samples_covered": [int(covered.sum()), int(covered.size)],
                      "ratio": [p / mm if mm > 0 else math.nan for p, mm in zip(predicted, measured)],
                      "points": runs[0]["points"], "repeats": len(runs),
                      "strain_measured_ue": runs[0]["strain_ue"],
                      "strain_predicted_ue": [pred_r.summary["sigma_exx_ue"], pred_r.summary["sigma_eyy_ue"]],
                      "instrument_sigma_left_frame_um": runs[0]["instrument_left_frame_um"]}}
    out["deformed"] = _deformed(truth, scenario, images, clean, gain, camera, models, settings, roi, Rws, predicted,
                                seed + 997)
    return out


def _covered_samples(sample_xy_px: np.ndarray, measured_xy_px: np.ndarray, step_px: float) -> np.ndarray:
    """Which ROI samples (left px, (N, 2)) have a measured point within one grid step, (N,) bool."""
    from scipy.spatial import cKDTree

    if len(measured_xy_px) == 0:
        return np.zeros(len(sample_xy_px), dtype=bool)
    distance, _ = cKDTree(measured_xy_px).query(np.asarray(sample_xy_px, float))
    return distance <= float(step_px)


def _nearest_samples(sample_xy_px: np.ndarray, measured_xy_px: np.ndarray) -> np.ndarray:
    """Index of the nearest ROI sample (left px) of every measured point, (M,) int."""
    from scipy.spatial import cKDTree

    return cKDTree(np.asarray(sample_xy_px, float)).query(np.asarray(measured_xy_px, float))[1]


def truth_rig(scenario):
    """The true rig of the rendered scenario (the designed rig at the render's scale)."""
    from workbench.experiments.specimen.scenes import rig_of

    return rig_of(scenario)


def _deformed(truth, scenario, images, clean, gain, camera, models, settings, roi, Rws, predicted, seed) -> dict:
    """The deformed state against the truth: random error per component (specimen frame), µm."""
    from measurement.stereo_dic import reference_shape

    rig = truth_rig(scenario)
    cams = (rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
    k = len(truth.files) - 1
    ref = {side: camera_image(clean[side], gain, camera, seed + i) for i, side in enumerate(("left", "right"))}
    de = {side: camera_image(read_grey(images / truth.files[k][side]).astype(np.float64), gain, camera, seed + 2 + i)
          for i, side in enumerate(("left", "right"))}
    shape = reference_shape(*cams, ref["left"], ref["right"], settings, mask=roi, noise=models)
    state = measure_state(*cams, shape, ref["left"], de["left"], de["right"], settings, name="deformed state")
    pix = np.column_stack([shape.x, shape.y]).astype(float)
    _, X_true = truth.points_of_interest(pix)
    U_true = X_true[k] - X_true[0]
    ok = state.valid & np.all(np.isfinite(U_true), axis=1)
    err = _spec_frame(np.where(ok[:, None], state.U_mm - U_true, np.nan), Rws) * 1e3
    mean = np.nanmean(err, axis=0)
    sig = None
    if state.cov_U_mm2 is not None:
        cov_s = np.asarray(Rws).T @ state.cov_U_mm2 @ np.asarray(Rws)
        sig = [_rms(1e3 * np.sqrt(np.clip(cov_s[ok, i, i], 0, None))) for i in range(3)]
    return {"state": truth.labels[k], "points": int(ok.sum()),
            "measured_um": [_std(err[:, i]) for i in range(3)], "mean_error_um": mean.tolist(),
            "instrument_sigma_um": sig, "predicted_static_um": predicted}
