"""``workbench design``: from a specimen and a parts list to a rig one can build, verified by rendering it.

:func:`run_design` reads the design file (:mod:`workbench.design.inputs`), samples the specimen's face
(:mod:`~workbench.design.surface`), tabulates the instrument's match covariance on the paint
(:mod:`~workbench.design.pattern`), searches and ranks every candidate rig (:mod:`~workbench.design.search`,
:mod:`~workbench.design.predict`), checks the chosen rig's tilts against an independent hinge-rule solver
(:func:`workbench.rigs.scheimpflug_tilt_for_plane`, which solves the lens' F for a fixed sensor distance where the
designer solves the sensor distance for a fixed F), predicts the named rigs to compare with (``compare``: the
paper's Table 1 rig, the ``scheimpflug`` rig), renders and measures the chosen and the best untilted rig
(:mod:`~workbench.design.verify`), and writes into ``--out``:

* ``design.json`` -- everything below as numbers (written last: its presence means the folder is complete);
* ``report.html`` (self-contained) and ``report.md`` -- the rigs drawn from above and from the side with the planes
  of sharp focus and the depth-of-field wedges, maps of the predicted noise and blur over the ROI for both rigs,
  the ranked candidates, the comparison, the verification (:mod:`~workbench.design.report`);
* ``rig_chosen/`` and ``rig_untilted/`` -- each rig as this project's calibration JSON (with its optics, so
  ``workbench render``/``twin`` can use it, and a real calibration's first guess) and as OpenCV YAML;
* ``candidates.csv`` -- every candidate tried with its figures or why it was rejected;
* ``verify/`` -- the renders and their truth (one folder per rig).
"""
from __future__ import annotations

import csv
import io
import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from labio.atomic import atomic_write_text

from .geometry import CandidateRig, Placement, SIDES
from .inputs import DesignInput, load_design
from .pattern import pattern_table
from .predict import Prediction, predict
from .search import precheck, search
from .surface import surface_of
from .verify import verify, write_rig_files

#: Named rigs a design may be compared with (:func:`workbench.rigs.get_rig`).
COMPARE_RIGS = ("paper", "scheimpflug")


@dataclass
class DesignResult:
    design: DesignInput
    surface: object
    search: object
    hinge_check: dict
    comparisons: dict
    verification: dict
    seconds: dict
    out_dir: Path


def hinge_check(candidate: CandidateRig, surface) -> dict:
    """The chosen rig's tilts against the independent solver of :mod:`workbench.rigs` for the same geometry."""
    from workbench.rigs import scheimpflug_tilt_for_plane

    c, n = surface.best_plane()
    out = {}
    for side in SIDES:
        cam = candidate.rig.camera(side)
        R, t = candidate.placement.R_cam_from_spec[side], candidate.placement.t_cam_from_spec_mm[side]
        a, b, F, rms = scheimpflug_tilt_for_plane(cam, R, t, c, n, candidate.rig.pixel_pitch_mm,
                                                  candidate.rig.f_number)
        out[side] = {"design_alpha_deg": cam.alpha_deg, "design_beta_deg": cam.beta_deg,
                     "hinge_rule_alpha_deg": a, "hinge_rule_beta_deg": b, "hinge_rule_focal_length_mm": F,
                     "lens_focal_length_mm": candidate.rig.lens_focal_length_mm[0],
                     "difference_deg": max(abs(a - cam.alpha_deg), abs(b - cam.beta_deg))}
    out["max_difference_deg"] = max(out[s]["difference_deg"] for s in SIDES)
    out["applies"] = candidate.tilted and not candidate.tilt_clamped
    return out


def candidate_from_rig(rig, f_number: float) -> CandidateRig:
    """A named rig (paper, scheimpflug) as a candidate: its cameras, its thin lenses (or a lens focused on the face
    centre), the specimen facing the cameras' bisector where the optical axes meet."""
    from workbench.experiments.bending.scenes import bending_specs
    from workbench.experiments.rigid_motion.scenes import specimen_reference_pose

    R0, t0 = specimen_reference_pose(rig)
    specs = bending_specs(rig, "thin", t0, f_number)
    F = (specs["left"].focal_length_mm, specs["right"].focal_length_mm)
    rig = replace(rig, lens_focal_length_mm=F, f_number=float(f_number))
    Rc, tc = {}, {}
    for side in SIDES:
        R, t = rig.pose(side)
        Rc[side] = R @ R0                 # X_cam = R (R0 X_spec + t0) + t
        tc[side] = R @ t0 + t
    d = float(np.linalg.norm(t0 - rig.camera_centre_mm("left")))
    axes = [rig.pose(s)[0].T @ np.array([0.0, 0.0, 1.0]) for s in SIDES]
    angle = math.degrees(math.acos(float(np.clip(axes[0] @ axes[1], -1, 1))))
    tilted = any(abs(a) > 1e-9 for s in SIDES for a in (rig.camera(s).alpha_deg, rig.camera(s).beta_deg))
    return CandidateRig(rig, specs, np.asarray(R0), np.asarray(t0), Placement(Rc, tc, d, angle), tilted,
                        camera_name=rig.name, lens_name=f"F {F[0]:.1f} / {F[1]:.1f} mm")


def compare(design: DesignInput, names, surface, table, f_number: float) -> dict:
    """Predictions for the named rigs with the design's first camera's noise, at the chosen f-number."""
    from workbench.rigs import get_rig

    out = {}
    camera = design.camera[0]
    for name in names:
        rig = get_rig(name, 1.0)
        cam = replace(camera, width_px=rig.left.width, height_px=rig.left.height,
                      pixel_pitch_um=rig.pixel_pitch_mm * 1e3)
        cand = candidate_from_rig(rig, f_number)
        try:
            p = predict(cand, surface, cam, design.lighting, design.search, table, speckle_mm=design.specimen.speckle_mm,
                        speckle_px_at_centre=design.specimen.speckle_px, depth_range_mm=design.specimen.depth_range_mm,
                        contrast=design.specimen.speckle_contrast)
        except ValueError as err:
            out[name] = {"error": str(err)}
            continue
        out[name] = {"prediction": p, "tilts_deg": {s: list(cand.tilts_deg(s)) for s in SIDES},
                     "working_distance_mm": cand.placement.distance_mm,
                     "stereo_angle_deg": cand.placement.stereo_angle_deg}
        if rig.lens_focal_length_mm is not None:
            out[name]["designer_tilts_deg"] = designer_tilts(cand)
    return out


def designer_tilts(cand: CandidateRig) -> dict:
    """The designer's hinge rule (:func:`workbench.design.geometry.hinge_rule`) for a named rig's own geometry and
    lenses (its cameras' poses, image size, pitch, F), the face plane where its optical axes meet: the tilts the
    designer would give that rig, beside the rig's own."""
    from .geometry import hinge_rule

    out = {}
    for i, side in enumerate(SIDES):
        cam = cand.rig.camera(side)
        a, b, v, _ = hinge_rule(cam.width, cam.height, cand.rig.pixel_pitch_mm, cand.rig.lens_focal_length_mm[i],
                                cand.placement.R_cam_from_spec[side], cand.placement.t_cam_from_spec_mm[side],
                                np.zeros(3), np.array([0.0, 0.0, -1.0]))
        out[side] = {"designer_alpha_deg": a, "designer_beta_deg": b, "rig_alpha_deg": cam.alpha_deg,
                     "rig_beta_deg": cam.beta_deg,
                     "difference_deg": max(abs(a - cam.alpha_deg), abs(b - cam.beta_deg))}
    out["max_difference_deg"] = max(out[s]["difference_deg"] for s in SIDES)
    return out


def _row(p: Prediction) -> dict:
    c = p.candidate
    s = p.summary
    return {"label": c.rig.name, "camera": c.camera_name, "lens": c.lens_name,
            "working_distance_mm": c.placement.distance_mm, "stereo_angle_deg": c.placement.stereo_angle_deg,
            "f_number": c.f_number, "tilted": c.tilted, "tilt_clamped": c.tilt_clamped,
            "alpha_left_deg": c.rig.left.alpha_deg, "beta_left_deg": c.rig.left.beta_deg,
            "alpha_right_deg": c.rig.right.alpha_deg, "beta_right_deg": c.rig.right.beta_deg,
            **{k: v for k, v in s.items() if not isinstance(v, list)},
            "speckle_px_min": s["speckle_px"][0], "speckle_px_max": s["speckle_px"][1]}


def candidates_csv(result) -> str:
    rows = [_row(p) for p in result.ranked]
    keys = list(rows[0]) if rows else ["label"]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=keys + ["rejected_because"], extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        writer.writerow(r)
    for r in result.rejected:
        writer.writerow({"label": r["label"], "rejected_because": r["reason"]})
    return buffer.getvalue()


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, Path):
        return str(value)
    return value


def run_design(design_or_path, out_dir, *, verify_rigs: bool | None = None, compare_with=(),
               progress=None) -> DesignResult:
    """Design a rig (module notes). ``verify_rigs`` overrides ``verify.enabled``; ``compare_with``: names of
    :data:`COMPARE_RIGS` to predict beside the design; ``progress(message)`` is told of each long step."""
    from workbench.config import to_dict

    from .report import write_report

    say = progress or (lambda message: None)
    design = load_design(design_or_path) if not isinstance(design_or_path, DesignInput) else design_or_path
    unknown = [n for n in compare_with if n not in COMPARE_RIGS]
    if unknown:
        raise ValueError(f"--compare {unknown[0]!r}: known rigs are {', '.join(COMPARE_RIGS)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "design.json").unlink(missing_ok=True)          # the folder is complete only when this is rewritten
    seconds = {}
    t = time.perf_counter()
    surface, specimen_file = surface_of(design.specimen, out / "specimen")
    say(f"specimen face: {surface.label}, {len(surface.points_mm)} ROI samples")
    precheck(design, surface)
    table = pattern_table(design.search.subset_px, design.search.order, contrast=design.specimen.speckle_contrast,
                          seed=design.seed)
    seconds["pattern_table"] = time.perf_counter() - t
    say(f"the instrument's match covariance tabulated on the paint ({seconds['pattern_table']:.1f} s)")
    t = time.perf_counter()
    result = search(design, surface, table,
                    progress=lambda i, n: say(f"candidate geometries {i}/{n}") if i == n or i % 10 == 0 else None)
    seconds["search"] = time.perf_counter() - t
    say(f"{result.tried} candidates, {len(result.ranked)} feasible, ranked in {seconds['search']:.1f} s")
    best, best_u = result.best, result.best_untilted
    check = hinge_check(best.candidate, surface) if best.candidate.tilted else {}
    comparisons = compare(design, compare_with, surface, table, best.candidate.f_number) if compare_with else {}
    files = {"chosen": write_rig_files(best.candidate, out / "rig_chosen")}
    if best_u is not None and best_u is not best:
        files["untilted"] = write_rig_files(best_u.candidate, out / "rig_untilted")
    atomic_write_text(out / "candidates.csv", candidates_csv(result))
    verification = {}
    do_verify = design.verify.enabled if verify_rigs is None else verify_rigs
    if do_verify:
        for key, p in (("chosen", best), ("untilted", best_u)):
            if p is None or (key == "untilted" and p is best):
                continue
            t = time.perf_counter()
            say(f"verifying the {key} rig by rendering it ({p.candidate.rig.name})")
            verification[key] = verify(design, p, surface, specimen_file, out / "verify" / key, table,
                                       progress=say if progress else None)
            seconds[f"verify_{key}"] = time.perf_counter() - t
    dr = DesignResult(design, surface, result, check, comparisons, verification, seconds, out)
    write_report(dr)
    doc = {"format": "workbench-design/1", "design": to_dict(design),
           "specimen": {"label": surface.label, "roi_mm": list(surface.roi_mm), "samples": len(surface.points_mm),
                        "file": str(specimen_file) if specimen_file else None},
           "search": {"tried": result.tried, "feasible": len(result.ranked), "rejected": len(result.rejected),
                      "seconds": seconds["search"]},
           "chosen": _row(best), "best_untilted": _row(best_u) if best_u else None,
           "best_tilted": _row(result.best_tilted) if result.best_tilted else None,
           "ratio_untilted_over_chosen": (best_u.summary["objective"] / best.summary["objective"]
                                          if best_u is not None else None),
           "mig_ratio_chosen_over_untilted": (best.summary["mig_grey_per_px"] / best_u.summary["mig_grey_per_px"]
                                              if best_u is not None else None),
           "hinge_check": check, "rig_files": files,
           "compare": {k: ({"error": v["error"]} if "error" in v else
                           {**_row(v["prediction"]), "tilts_deg": v["tilts_deg"],
                            "designer_tilts_deg": v.get("designer_tilts_deg")}) for k, v in comparisons.items()},
           "verification": verification, "seconds": seconds}
    atomic_write_text(out / "design.json", json.dumps(_jsonable(doc), indent=1))
    return dr
