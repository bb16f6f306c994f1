"""The what-if table: the user's settings changed one at a time, each measured on the twin.

Rows (each against the user's baseline, on the same noise draws so that the differences are sharp):

* subset x 0.75 and x 1.5 (odd, at least 11 px), the other shape-function order, step x 2 and / 2 (the
  half step only while the baseline has under :data:`MAX_POINTS_HALF_STEP` points: it quadruples them),
  strain window - 2 and + 4 grid points (a strain-only change: recomputed from the baseline's displacements);
* each with its predicted displacement noise (µm, or px for a one-camera twin), strain noise (µε), the
  instrument's own predicted static sigma beside it (:mod:`measurement.uncertainty`), and what it costs in
  spatial resolution (the theoretical l10 of the subset and order, and the virtual strain gauge
  ``(window - 1) step + subset``);
* ranked by the predicted change of the objective (displacement noise by default; ``strain`` ranks by the
  strain noise).

A thin-lens rig's f-number and focus add rows (:mod:`workbench.twin.optics`, built by
:func:`workbench.twin.run.optics_rows`) when the user states the f-number and pixel pitch; a calibration file
describes a pinhole camera, so without them those rows are listed as not applicable, with the reason.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..experiments.dic2d.star import theoretical_l10_px
from .measure import strain_noise

#: The half-step row is skipped above this many baseline points (it would quadruple the work).
MAX_POINTS_HALF_STEP = 100_000
OBJECTIVES = ("displacement", "strain")


def _odd(value: float) -> int:
    v = int(round(value))
    return v if v % 2 else v + 1


def variants(settings, strain_window: int | None, points: int, max_subset: int) -> list[tuple[str, object, object]]:
    """``(label, DICSettings, strain_window)`` of each what-if row (module notes), baseline first."""
    rows = [("baseline (your settings)", settings, strain_window)]
    for factor in (0.75, 1.5):
        s = max(11, _odd(settings.subset_size * factor))
        if s != settings.subset_size and s <= max_subset:
            rows.append((f"subset {settings.subset_size} -> {s} px", replace(settings, subset_size=s), strain_window))
    other = 1 if settings.order == 2 else 2
    rows.append((f"shape function order {settings.order} -> {other}", replace(settings, order=other), strain_window))
    rows.append((f"step {settings.step} -> {2 * settings.step} px", replace(settings, step=2 * settings.step),
                 strain_window))
    if settings.step >= 2 and points <= MAX_POINTS_HALF_STEP:
        rows.append((f"step {settings.step} -> {settings.step // 2} px", replace(settings, step=settings.step // 2),
                     strain_window))
    if strain_window is not None:
        if strain_window - 2 >= 3:
            rows.append((f"strain window {strain_window} -> {strain_window - 2} points", settings, strain_window - 2))
        rows.append((f"strain window {strain_window} -> {strain_window + 4} points", settings, strain_window + 4))
    return rows


def displacement_figure(noise: dict) -> float:
    """One number for a displacement noise dict: the RMS of the components (µm or px)."""
    values = [v for v in noise.values() if np.isfinite(v)]
    return float(np.sqrt(np.mean(np.square(values)))) if values else math.nan


def strain_figure(strain: dict) -> float:
    values = [strain[k] for k in ("E11", "E22") if k in strain and np.isfinite(strain[k])]
    return float(np.sqrt(np.mean(np.square(values)))) if values else math.nan


def vsg_px(settings, window) -> float:
    return float((window - 1) * settings.step + settings.subset_size) if window is not None else math.nan


def strain_only(run, window: int | None) -> dict:
    """The strain noise of an already measured static run with another strain window."""
    if run.kind == "stereo":
        X_ref = run.X_ref_mm
        X_def = X_ref + run.values / 1e3
    else:
        X_ref = np.column_stack([run.x_px, run.y_px, np.zeros_like(run.x_px)])
        X_def = X_ref + np.column_stack([run.values, np.zeros_like(run.x_px)])
    ok = np.all(np.isfinite(X_def), axis=1)
    return strain_noise(np.where(ok[:, None], X_ref, np.nan), np.where(ok[:, None], X_def, np.nan), run.x_px,
                         run.y_px, window)


def rank(rows: list[dict], objective: str = "displacement") -> list[dict]:
    """Rows sorted by the predicted change of the objective (most negative first), baseline kept first; each row
    gets ``change`` (relative to the baseline), ``rank`` (1 = the top recommendation; None for the baseline and for
    rows that do not improve by 2 %) and ``keeps_resolution`` (its l10 and virtual strain gauge within 10 % of the
    baseline's: a change that buys noise with resolution does not)."""
    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
    key = "displacement_noise" if objective == "displacement" else "strain_noise_ue"
    base = rows[0][key]
    for row in rows:
        row["objective"] = objective
        row["change"] = (row[key] / base - 1.0) if (base and np.isfinite(base) and np.isfinite(row[key])) else math.nan
    base_l10, base_vsg = rows[0].get("l10_theory_px", math.nan), rows[0].get("vsg_px", math.nan)
    for row in rows:
        # the same spatial resolution: l10 of the subset/order and the virtual strain gauge within 10 % of yours
        row["keeps_resolution"] = bool(row.get("l10_theory_px", math.nan) <= 1.1 * base_l10 and
                                       not row.get("vsg_px", math.nan) > 1.1 * base_vsg)
    rest = sorted(rows[1:], key=lambda r: (math.inf if not np.isfinite(r["change"]) else r["change"]))
    k = 1
    for row in rest:
        row["rank"] = k if np.isfinite(row["change"]) and row["change"] < -0.02 else None
        k += row["rank"] is not None
    rows[0]["rank"] = None
    return [rows[0], *rest]


def advice(rows: list[dict]) -> dict:
    """The what-if verdict, the one the report and the terminal both state.

    Returns ``{"keeps_resolution": row or None, "noise_only": row or None, "lines": [str, ...]}``: the best ranked
    change whose spatial resolution stays yours (``keeps_resolution`` of :func:`rank`), the top of the noise-only
    ranking, and the sentences that say so (the noise-only top is named with what it costs in l10 and strain gauge
    when it is not the change that keeps the resolution). Rows as :func:`rank` returns them.
    """
    ranked = [r for r in rows if r.get("rank")]
    same = next((r for r in ranked if r.get("keeps_resolution")), None)
    top = ranked[0] if ranked else None
    if top is None:
        return {"keeps_resolution": None, "noise_only": None,
                "lines": ["no change of one setting lowers the predicted noise by more than 2 %: keep yours"]}
    objective = top.get("objective", "displacement")
    base = rows[0]

    def change(row) -> str:
        return f"{100 * row['change']:+.0f} % {objective} noise"

    lines = ["best change that keeps your spatial resolution (l10 and strain gauge within 10 %): " +
             (f"{same['label']} ({change(same)})" if same else
              "none; every change that lowers the noise costs resolution")]
    if top is not same:
        cost = [f"l10 {_num(base.get('l10_theory_px'))} -> {_num(top.get('l10_theory_px'))} px"]
        if _num(top.get("vsg_px")) != _num(base.get("vsg_px")):
            cost.append(f"strain gauge {_num(base.get('vsg_px'))} -> {_num(top.get('vsg_px'))} px")
        lines.append(f"lowest noise at any resolution: {top['label']} ({change(top)}, at the cost of "
                     f"{', '.join(cost)})")
    return {"keeps_resolution": same, "noise_only": top, "lines": lines}


def _num(value) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{value:.3g}"


def theory_l10(settings) -> float:
    return float(theoretical_l10_px(settings.subset_size, settings.order))
