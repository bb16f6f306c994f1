"""Stereo classes of the uncertainty proof: catalog specimens rendered through the paper rig, several noise draws.

Each catalog specimen (the beam in bending, the plate with a hole, the notched coupon: FE solved with scikit-fem,
:mod:`scenes.specimens.catalog`) is rendered as ``workbench reproduce catalog`` renders it (load steps, then a rigid tour
of 4 moves, then a static state) ``draws`` times, each with a new sensor-noise seed (``render.noise_seed``: the
same scene, new noise; each draw is a dataset of the store). The instrument measures every draw with the true rig
and fits the noise to its own stereo match's residuals (no static pair given: its default). Classes pool the states
of one kind: "rigid move" (the rigid tours and the static states of the three specimens), and the load steps of
each specimen; "reference shape" scores X, Y, Z.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from .coverage import coverage_figures, random_deviation, verdict

#: Strain window (grid points per side, first-order fit) of the strain classes.
STRAIN_WINDOW = 9
#: The catalog specimens measured, and the class their load steps form.
SPECIMENS = {"beam": "bending (beam)", "plate_with_hole": "plate with a hole", "notched_coupon": "notched coupon"}


def _draw(scenario, d: int, store, progress: bool):
    from workbench.experiments.specimen.scenes import load_specimen_truth, render_specimen
    from workbench.scenario import dataset_parts

    sc = replace(scenario, render=replace(scenario.render, noise_seed=1000 + d))
    key, content = dataset_parts(sc)["states"]
    images, _ = store.ensure("specimen", key, content, lambda f: render_specimen(sc, f, progress=progress,
                                                                                 overwrite=True))
    return images, load_specimen_truth(images)


def measure_draws(name: str, out_dir: Path, *, scale: float, draws: int, subset_px: int, step_px: int, store,
                  progress: bool = False) -> dict:
    """Every draw of one catalog specimen measured: per state the displacements, their sigma and flags.

    Returns ``{"labels", "X" (D, N, 3), "sigma_X" (D, N, 3), "U" (D, S, N, 3), "sigma_U", "flag" (D, S, N),
    "E" (D, S, N, 3), "sigma_E" (D, S, N, 3), "U_true" (S, N, 3), "noise_grey" (D,)}`` with S the deformed states
    (E: E11, E22, E12 of a 9-point strain window, first order, in the left camera frame); NaN where a draw did not
    measure a point.
    """
    from measurement.calibration.io import CalibratedRig
    from measurement.dic import DICSettings
    from measurement.image_io import read_grey
    from measurement.stereo_dic import StereoMatchError, measure_state, reference_shape
    from measurement.uncertainty.stereo import sigmas
    from scenes.specimens.catalog import CATALOG, write_pvd
    from labio.atomic import atomic_write_text
    from workbench.config import load_config
    from workbench.experiments.specimen.case import measurable_mask
    from workbench.experiments.specimen.catalog import scenario_text
    from workbench.experiments.specimen.run import rigid_tour_extras
    from workbench.experiments.specimen.scenes import rig_of
    from workbench.scenario import Scenario, with_specimen_paths

    fe_dir = Path(out_dir) / "fe" / name
    result = CATALOG[name]()
    pvd = write_pvd(result, fe_dir)
    atomic_write_text(fe_dir / "scenario.toml", scenario_text(name, pvd.name, scale, rigid_tour_extras(scale)))
    scenario = with_specimen_paths(load_config(Scenario, fe_dir / "scenario.toml"), fe_dir)
    true = rig_of(scenario)
    rig = CalibratedRig("rmm", true.left, true.right, true.R_right_from_left, true.T_right_from_left_mm)
    cams = (rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
    settings = DICSettings(subset_size=subset_px, step=step_px, order=2)
    from measurement.strain import surface_strain
    from measurement.uncertainty.stereo import triangulation_sensitivity
    from measurement.uncertainty.strain import pair_covariances, state_strain_sigma

    X, sX, U, sU, flags, noise, E, sE = [], [], [], [], [], [], [], []
    labels = U_true = None
    for d in range(draws):
        images, truth = _draw(scenario, d, store, progress)
        left_ref = read_grey(images / truth.files[0]["left"])
        right_ref = read_grey(images / truth.files[0]["right"])
        shape = reference_shape(*cams, left_ref, right_ref, settings, mask=measurable_mask(truth, subset_px))
        if labels is None:
            labels = list(truth.labels)[1:]
            _, X_true = truth.points_of_interest(np.column_stack([shape.x, shape.y]).astype(float))
            U_true = np.array([X_true[k] - X_true[0] for k in range(1, len(truth.files))])
        n = shape.x.size
        X.append(np.where(shape.valid[:, None], shape.X_mm, np.nan))
        sX.append(sigmas(shape.cov_X_mm2))
        noise.append(shape.noise["left"].sigma_grey)
        grid = shape.grid
        pairs = pair_covariances(shape.reference, shape.subsets, shape.right_match.grid_index, grid.shape, grid.step,
                                 window=STRAIN_WINDOW)
        G_ref = triangulation_sensitivity(*cams, shape.X_mm)

        def on_grid(v):
            out = np.full(grid.shape + (3,), np.nan)
            out[grid.active] = v
            return out

        u_states, s_states, f_states, e_states, se_states = [], [], [], [], []
        for k in range(1, len(truth.files)):
            try:
                state = measure_state(*cams, shape, left_ref, read_grey(images / truth.files[k]["left"]),
                                      read_grey(images / truth.files[k]["right"]), settings, name=f"state {k}")
                u_states.append(np.where(state.valid[:, None], state.U_mm, np.nan))
                s_states.append(sigmas(state.cov_U_mm2))
                f_states.append(state.flag.astype(np.int8))
                ok = state.valid & shape.valid
                strain = surface_strain(on_grid(np.where(ok[:, None], shape.X_mm, np.nan)),
                                        on_grid(np.where(ok[:, None], state.X_mm, np.nan)), window=STRAIN_WINDOW)
                G_def = triangulation_sensitivity(*cams, state.X_mm)
                e_states.append(np.stack([strain.E11, strain.E22, strain.E12], -1)[grid.active])
                se_states.append(state_strain_sigma(shape, state, strain, G_ref, G_def, pairs)[grid.active])
            except StereoMatchError:
                for a in (u_states, s_states, e_states, se_states):
                    a.append(np.full((n, 3), np.nan))
                f_states.append(np.zeros(n, np.int8))
        U.append(u_states)
        sU.append(s_states)
        flags.append(f_states)
        E.append(e_states)
        sE.append(se_states)
    return {"labels": labels, "X": np.array(X), "sigma_X": np.array(sX), "U": np.array(U), "sigma_U": np.array(sU),
            "flag": np.array(flags), "E": np.array(E), "sigma_E": np.array(sE), "U_true": U_true,
            "noise_grey": np.array(noise)}


def _class_figures(name: str, values: np.ndarray, sigma: np.ndarray, flags: np.ndarray, truth: np.ndarray | None,
                   names: tuple[str, ...], noise_grey: float, settings: dict, *, scale: float = 1e3,
                   unit: str = "µm") -> dict:
    """Coverage figures of one class. ``values``/``sigma`` (D, N, 3) mm (or strain), ``flags`` (D, N), ``truth``
    (N, 3); reported in ``unit`` after multiplying by ``scale``."""
    measured = np.all(np.isfinite(values[..., 0]), axis=0)
    trusted = np.all(flags == 0, axis=0)
    flagged_fraction = float(np.count_nonzero(measured & ~trusted) / max(1, measured.sum()))
    keep = measured & trusted
    deviation = random_deviation(values[:, keep]) * scale
    s = sigma[:, keep] * scale
    figures = coverage_figures(deviation, s, names)
    out = {"class": name, "kind": "stereo", "settings": settings, "components": figures,
           "flagged_fraction": flagged_fraction,
           "median_sigma": [float(np.nanmedian(s[..., c])) for c in range(3)], "unit": unit,
           "noise_grey": noise_grey, "noise_true_grey": float(math.hypot(1.0, 12 ** -0.5)),
           "verdict": verdict(figures, flagged_fraction)}
    z = (deviation / s).reshape(-1, 3)
    out["z"] = z[np.all(np.isfinite(z), axis=1)]
    if truth is not None:
        error = (values[:, keep] - truth[keep]) * scale
        bias = np.nanmean(error, axis=0)
        out["total_rmse"] = [float(np.sqrt(np.nanmean(error[..., c] ** 2))) for c in range(3)]
        out["bias_rms"] = [float(np.sqrt(np.nanmean(bias[:, c] ** 2))) for c in range(3)]
    return out


def run_stereo_classes(out_dir: Path, *, scale: float = 0.25, draws: int = 6, subset_px: int = 33, step_px: int = 8,
                       store=None, progress: bool = False, specimens=tuple(SPECIMENS)) -> list[dict]:
    """The stereo classes (module notes): one figures dict per class."""
    from workbench.store import DatasetStore

    store = store if isinstance(store, DatasetStore) else DatasetStore(store)
    settings = {"scale": scale, "draws": draws, "subset_px": subset_px, "step_px": step_px, "order": 2}
    per = {name: measure_draws(name, out_dir, scale=scale, draws=draws, subset_px=subset_px, step_px=step_px,
                               store=store, progress=progress) for name in specimens}
    classes = []
    rigid_v, rigid_s, rigid_f, rigid_t, noise = [], [], [], [], []
    for name, m in per.items():
        noise.append(float(np.mean(m["noise_grey"])))
        steps = [i for i, label in enumerate(m["labels"]) if label.startswith("step")]
        others = [i for i, label in enumerate(m["labels"]) if not label.startswith("step")]
        # states of one kind pooled: (D, S, N, 3) -> (D, S N, 3)
        def pool(idx, key):
            a = m[key][:, idx]
            return a.reshape(a.shape[0], -1, *a.shape[3:])
        classes.append(_class_figures(SPECIMENS[name], pool(steps, "U"), pool(steps, "sigma_U"), pool(steps, "flag"),
                                      m["U_true"][steps].reshape(-1, 3), ("U", "V", "W"), noise[-1],
                                      settings | {"specimen": name, "states": [m["labels"][i] for i in steps]}))
        classes.append(_class_figures(f"{SPECIMENS[name]}: strain", pool(steps, "E"), pool(steps, "sigma_E"),
                                      pool(steps, "flag"), None, ("E11", "E22", "E12"), noise[-1],
                                      settings | {"specimen": name, "strain_window": STRAIN_WINDOW},
                                      scale=1e6, unit="µε"))
        rigid_v.append(pool(others, "U"))
        rigid_s.append(pool(others, "sigma_U"))
        rigid_f.append(pool(others, "flag"))
        rigid_t.append(m["U_true"][others].reshape(-1, 3))
    classes.insert(0, _class_figures("rigid move", np.concatenate(rigid_v, 1), np.concatenate(rigid_s, 1),
                                     np.concatenate(rigid_f, 1), np.concatenate(rigid_t, 0), ("U", "V", "W"),
                                     float(np.mean(noise)), settings | {"specimens": list(per)}))
    X = np.concatenate([m["X"] for m in per.values()], 1)
    sX = np.concatenate([m["sigma_X"] for m in per.values()], 1)
    classes.insert(0, _class_figures("reference shape", X, sX, np.zeros(X.shape[:2], np.int8), None,
                                     ("X", "Y", "Z"), float(np.mean(noise)), settings | {"specimens": list(per)}))
    return classes
