"""The ``specimen`` study case: a specimen of one's own (mesh or FE file) rendered in stereo and measured.

One dataset (``specimen``: every state in both cameras, :mod:`workbench.experiments.specimen.scenes`), measured by
the instrument with the true rig (``instrument.calibration = "true"``: a specimen case studies the DIC, not the
calibration) on the measurable pixels of the left reference image (the truth's mask, eroded by half a subset),
scored per state against the exact displacement of every material point.

Metrics per state (dimension ``state``): ``rms_displacement_error_um`` (3-D vector error of the measured
displacement from state 0, RMS over the points), ``mean_displacement_error_um`` (its mean magnitude along the
mean error direction: a bias), ``points_fraction`` (of the reference points measured and visible in the state).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.scenario import Instrument, Scenario, dataset_parts

METRICS = {"rms_displacement_error_um": "RMS of the 3-D displacement error against the FE truth (µm)",
           "mean_displacement_error_um": "length of the mean 3-D displacement error (µm): a bias",
           "points_fraction": "fraction of the reference points measured in the state"}
FLOORS: dict = {}


def check(scenario: Scenario, instrument: Instrument | None = None) -> None:
    """Refuse what this experiment cannot do (before a study starts)."""
    if not scenario.specimen.mesh:
        raise ValueError("scenario.specimen.mesh: no specimen file given")
    if not Path(scenario.specimen.mesh).is_file():
        raise ValueError(f"scenario.specimen.mesh: {scenario.specimen.mesh}: no such file")
    if scenario.render.bit_depth != 8:
        raise ValueError(f"scenario.render.bit_depth = {scenario.render.bit_depth}: specimen renders are 8-bit images")
    if instrument is not None and instrument.calibration != "true":
        raise ValueError("instrument.calibration = 'rendered' is not available for specimen cases yet: use 'true' "
                         "(the true rig)")


def render_states(scenario: Scenario, folder: Path) -> None:
    from workbench.experiments.specimen.scenes import render_specimen

    render_specimen(scenario, folder, progress=False, overwrite=True)


def measurable_mask(truth, subset_px: int) -> np.ndarray:
    """Left reference pixels whose whole subset sees measurable surface (the truth's mask, eroded)."""
    import cv2

    ok = (truth.maps["left"].mask == 0).astype(np.uint8)
    r = int(subset_px) // 2
    return cv2.erode(ok, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderValue=0).astype(bool)


def run(scenario: Scenario, instrument: Instrument, store) -> dict:
    """Study entry point: render (or reuse) the dataset, measure every state with the true rig, score."""
    from measurement.calibration.io import CalibratedRig
    from measurement.dic import DICSettings
    from measurement.image_io import read_grey
    from measurement.stereo_dic import StereoMatchError, measure_state, reference_shape
    from workbench.experiments.specimen.scenes import load_specimen_truth, rig_of

    check(scenario, instrument)
    key, content = dataset_parts(scenario)["states"]
    images, reused = store.ensure("specimen", key, content, lambda f: render_states(scenario, f))
    truth = load_specimen_truth(images)
    rig_true = rig_of(scenario)
    rig = CalibratedRig("rmm", rig_true.left, rig_true.right, rig_true.R_right_from_left, rig_true.T_right_from_left_mm)
    settings = DICSettings(subset_size=instrument.subset_px, step=instrument.step_px, order=instrument.shape_order,
                           interpolation=instrument.interpolation, lowpass_sigma_px=instrument.prefilter_sigma_px)
    left_ref = read_grey(images / truth.files[0]["left"])
    right_ref = read_grey(images / truth.files[0]["right"])
    shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, left_ref, right_ref,
                            settings, mask=measurable_mask(truth, instrument.subset_px))
    _, X_true = truth.points_of_interest(np.column_stack([shape.x, shape.y]).astype(float))
    rms, mean, fraction = [], [], []
    previous = None     # each state seeds the next (measure_state's warm start)
    for k in range(1, len(truth.files)):
        try:
            state = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape,
                                  left_ref, read_grey(images / truth.files[k]["left"]),
                                  read_grey(images / truth.files[k]["right"]), settings, name=f"state {k}",
                                  previous=previous)
        except StereoMatchError:
            rms.append(float("nan"))
            mean.append(float("nan"))
            fraction.append(0.0)
            continue
        previous = state
        ok = state.valid & shape.valid & np.all(np.isfinite(X_true[k]), axis=1) & np.all(np.isfinite(X_true[0]), axis=1)
        err = state.U_mm[ok] - (X_true[k] - X_true[0])[ok]
        rms.append(float(1e3 * np.sqrt(np.mean(np.sum(err ** 2, axis=1)))) if ok.any() else float("nan"))
        mean.append(float(1e3 * np.linalg.norm(err.mean(axis=0))) if ok.any() else float("nan"))
        fraction.append(float(ok.sum() / max(1, shape.valid.sum())))
    states = list(range(1, len(truth.files)))
    metrics = {"rms_displacement_error_um": rms, "mean_displacement_error_um": mean, "points_fraction": fraction}
    return {"metrics": metrics, "dims": {k: ["state"] for k in metrics}, "coords": {"state": states},
            "reused": {"states": reused}}
