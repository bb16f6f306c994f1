"""The search: every camera x lens x working distance x stereo angle x f-number, tilted (hinge rule) and not.

Each candidate is built (:func:`workbench.design.geometry.build_candidate`; the geometry is shared by all
f-numbers of a lens) and predicted (:func:`workbench.design.predict.predict`), analytically: no rendering. A
candidate is *feasible* when every ROI point stays inside both images over the depth travel (with a half subset's
margin), the cameras keep the stand-off and side space of the constraints and the in-focus fraction reaches
``search.min_in_focus_fraction``. The ranking is by the quantity that matters (:func:`~workbench.design.predict.
objective`). When nothing is feasible, :class:`InfeasibleDesignError` names the constraint and the nearest value
that would have been feasible (a longer working distance, a shorter lens, a smaller depth range).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .geometry import build_candidate
from .inputs import DesignInput, f_numbers_of
from .predict import OutOfViewError, Prediction, objective, predict


class InfeasibleDesignError(ValueError):
    """No candidate meets the constraints; the message names the constraint and the nearest feasible value."""


@dataclass
class SearchResult:
    """All candidates tried, the feasible ones ranked, and why the others failed.

    Attributes
    ----------
    ranked : list of Prediction
        Feasible candidates, best first.
    rejected : list of dict
        ``{"label", "reason"}`` of every other candidate.
    best, best_untilted : Prediction or None
        The best candidate overall and the best with untilted sensors.
    tried : int
    seconds : float
    """

    ranked: list
    rejected: list
    best: Prediction | None
    best_untilted: Prediction | None
    best_tilted: Prediction | None
    tried: int
    seconds: float
    notes: list = field(default_factory=list)


def _grid(lo: float, hi: float, n: int) -> list[float]:
    return [float(lo)] if n == 1 or lo == hi else [float(v) for v in np.linspace(lo, hi, n)]


def candidate_grid(design: DesignInput) -> list[tuple]:
    """``(camera_index, lens_index, distance_mm, angle_deg, tilt)`` of every geometry (f-numbers apart)."""
    c = design.constraints
    tilts = (True, False) if design.adapter.tilt_max_deg > 0 else (False,)
    return [(ci, li, D, a, t) for ci in range(len(design.camera)) for li in range(len(design.lens))
            for D in _grid(*c.working_distance_mm, design.search.distances)
            for a in _grid(*c.stereo_angle_deg, design.search.angles) for t in tilts]


def constraint_violation(design: DesignInput, distance_mm: float, angle_deg: float, focal_length_mm: float) -> str:
    """Why a geometry breaks the constraints ('' when it does not)."""
    c = design.constraints
    h = math.radians(angle_deg) / 2
    standoff = distance_mm * math.cos(h)
    side = distance_mm * math.sin(h)
    if standoff < c.min_standoff_mm:
        return f"stand-off {standoff:.0f} mm < constraints.min_standoff_mm {c.min_standoff_mm:g}"
    if c.max_side_mm is not None and side > c.max_side_mm:
        return f"sideways offset {side:.0f} mm > constraints.max_side_mm {c.max_side_mm:g}"
    if distance_mm <= 2 * focal_length_mm:
        return f"working distance {distance_mm:.0f} mm is within twice the focal length {focal_length_mm:g} mm"
    return ""


def search(design: DesignInput, surface, table, *, progress=None) -> SearchResult:
    """Build, predict and rank every candidate (module notes)."""
    t0 = time.perf_counter()
    s = design.specimen
    ranked, rejected = [], []
    geometries = candidate_grid(design)
    tried = 0
    for gi, (ci, li, D, angle, tilt) in enumerate(geometries):
        camera, lens = design.camera[ci], design.lens[li]
        numbers = f_numbers_of(lens, design.search)
        base = f"{camera.name} / {lens.name}, D {D:.0f} mm, {angle:.1f} deg, {'tilted' if tilt else 'untilted'}"
        why = constraint_violation(design, D, angle, lens.focal_length_mm)
        if why:
            tried += len(numbers)
            rejected += [{"label": f"{base}, f/{N:g}", "reason": why} for N in numbers]
            continue
        plane_c, plane_n = surface.best_plane()
        geometry = None
        for N in numbers:
            tried += 1
            label = f"{base}, f/{N:g}"
            try:
                if geometry is None:
                    geometry = build_candidate(camera, lens, N, D, angle, tilt=tilt,
                                               tilt_max_deg=design.adapter.tilt_max_deg, plane_centre_mm=plane_c,
                                               plane_normal=plane_n, name=label)
                cand = replace(geometry, rig=replace(geometry.rig, name=label, f_number=float(N)),
                               specs={k: v.with_(f_number=float(N)) for k, v in geometry.specs.items()})
                p = predict(cand, surface, camera, design.lighting, design.search, table,
                            speckle_mm=s.speckle_mm, speckle_px_at_centre=s.speckle_px,
                            depth_range_mm=s.depth_range_mm, contrast=s.speckle_contrast)
            except (OutOfViewError, ValueError) as err:
                rejected.append({"label": label, "reason": str(err)})
                continue
            if p.summary["in_focus_fraction"] < design.search.min_in_focus_fraction:
                rejected.append({"label": label, "reason": f"in-focus fraction {p.summary['in_focus_fraction']:.2f} < "
                                                           f"search.min_in_focus_fraction "
                                                           f"{design.search.min_in_focus_fraction:g}"})
                continue
            p.summary["objective"] = objective(p.summary, s.quantity, s.component)
            p.summary["tilted"] = cand.tilted
            ranked.append(p)
        if progress is not None:
            progress(gi + 1, len(geometries))
    ranked.sort(key=lambda p: p.summary["objective"])
    best_u = next((p for p in ranked if not p.candidate.tilted), None)
    best_t = next((p for p in ranked if p.candidate.tilted), None)
    result = SearchResult(ranked, rejected, ranked[0] if ranked else None, best_u, best_t, tried,
                          time.perf_counter() - t0)
    if not ranked:
        raise InfeasibleDesignError(explain_infeasible(design, surface, rejected))
    return result


def precheck(design: DesignInput, surface) -> None:
    """Refuse, before any work, a face that no camera and lens on offer can see whole at the most favourable allowed
    geometry (longest distance, smallest stereo angle): :class:`InfeasibleDesignError` with the nearest feasible
    distance."""
    c = design.constraints
    D, angle = c.working_distance_mm[1], c.stereo_angle_deg[0]
    rejected = []
    for camera in design.camera:
        for lens in design.lens:
            N = f_numbers_of(lens, design.search)[0]
            try:
                cand = build_candidate(camera, lens, N, D, angle, tilt=False, tilt_max_deg=0.0)
                predict(cand, surface, camera, design.lighting, design.search, _NullTable(), speckle_mm=1.0,
                        depth_range_mm=design.specimen.depth_range_mm)
                return
            except (OutOfViewError, ValueError) as err:
                rejected.append({"label": f"{camera.name} / {lens.name}", "reason": str(err)})
    raise InfeasibleDesignError(explain_infeasible(design, surface, rejected))


def explain_infeasible(design: DesignInput, surface, rejected: list) -> str:
    """The constraint no candidate met and the nearest feasible value (module notes)."""
    reasons = [r["reason"] for r in rejected]
    view = [r for r in reasons if "does not see ROI point" in r]
    focus = [r for r in reasons if r.startswith("in-focus fraction")]
    c = design.constraints
    if view and len(view) >= len(reasons) - len(focus):
        # how far away would the ROI fit? (the field of view grows with the distance)
        lo, hi = c.working_distance_mm
        angle = 0.5 * sum(c.stereo_angle_deg)
        best = None
        for camera in design.camera:
            for lens in design.lens:
                N = f_numbers_of(lens, design.search)[0]
                for D in np.geomspace(max(hi, 2.1 * lens.focal_length_mm), 50 * max(hi, lens.focal_length_mm), 40):
                    try:
                        cand = build_candidate(camera, lens, N, float(D), angle, tilt=False, tilt_max_deg=0.0)
                        predict(cand, surface, camera, design.lighting, design.search, _NullTable(),
                                speckle_mm=1.0, depth_range_mm=design.specimen.depth_range_mm)
                    except (OutOfViewError, ValueError):
                        continue
                    if best is None or D < best[0]:
                        best = (float(D), camera.name, lens.name)
                    break
        nearest = (f"; the nearest feasible: working distance {best[0]:.0f} mm with {best[1]} / {best[2]} "
                   f"(constraints.working_distance_mm allows up to {hi:g})") if best else ""
        return (f"no lens on offer reaches the field of view at the allowed distance: the ROI "
                f"{[round(v, 2) for v in surface.roi_mm]} mm does not fit both images{nearest}")
    if focus:
        fractions = [float(r.split()[2]) for r in focus]
        return (f"the depth range exceeds any depth of field on offer: search.min_in_focus_fraction "
                f"{design.search.min_in_focus_fraction:g} is not reached (best in-focus fraction {max(fractions):.2f}; "
                f"specimen.depth_range_mm {design.specimen.depth_range_mm:g} mm)")
    common = max(set(reasons), key=reasons.count) if reasons else "no candidate"
    return f"no candidate meets the constraints ({len(reasons)} rejected; most often: {common})"


class _NullTable:
    """A pattern table that only answers the field-of-view question (the covariance is not needed there)."""

    def covariance(self, s, c, g):
        return np.ones_like(np.asarray(s, float))

    def noise_gain(self, s, c, g):
        return np.ones_like(np.asarray(s, float))

    def mig(self, s, c, g):
        return np.ones_like(np.asarray(s, float))

    def out_of_range(self, s, c, g):
        return np.zeros(np.shape(s), bool)
