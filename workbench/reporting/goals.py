"""Goals in µm of a run at reduced image scale: one rule and one wording for every table that states them.

A run at ``scale`` < 1 sees pixels ``1 / scale`` times larger on the specimen, so a displacement goal in µm set at
full resolution is multiplied by ``1 / scale``. The experiments' own reports and the paper's summary both take
their µm goals from here, so no two tables of one run state different goals for the same figure.
"""
from __future__ import annotations


def footprint_factor(scale: float) -> float:
    """How many times larger a pixel's footprint on the specimen is at ``scale`` than at full resolution.

    Parameters
    ----------
    scale : float
        Image scale of the run, in (0, 1] (1: full resolution).

    Returns
    -------
    float
        ``1 / scale``.
    """
    scale = float(scale)
    if not scale > 0:
        raise ValueError(f"image scale must be > 0, got {scale}")
    return 1.0 / scale


def scaled_note(scale: float) -> str:
    """The words that say a goal was scaled: ``"scaled ×4 with the pixel footprint"``; ``""`` at full scale.

    Parameters
    ----------
    scale : float
        Image scale of the run.

    Returns
    -------
    str
        The note, without brackets, or an empty string when ``scale`` is 1.
    """
    factor = footprint_factor(scale)
    return "" if factor == 1.0 else f"scaled ×{factor:g} with the pixel footprint"


def um_goal_text(goal_um: float, scale: float, relation: str = "≤", digits: int = 2) -> str:
    """A µm goal as every table states it: ``"≤ 0.40 µm (scaled ×4 with the pixel footprint)"``.

    Parameters
    ----------
    goal_um : float
        The goal at this run's scale (already multiplied by :func:`footprint_factor`), µm.
    scale : float
        Image scale of the run (only for the note).
    relation : str
        What the goal bounds, e.g. ``"≤"`` or ``"abs ≤"``.
    digits : int
        Decimals of the goal.

    Returns
    -------
    str
        The goal, its unit and, when scaled, the note in brackets.
    """
    note = scaled_note(scale)
    return f"{relation} {goal_um:.{digits}f} µm" + (f" ({note})" if note else "")


__all__ = ["footprint_factor", "scaled_note", "um_goal_text"]
