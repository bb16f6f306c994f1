"""Argument checks shared by the truth-side error sources (one wording for every module's messages)."""
from __future__ import annotations

import numpy as np


def finite_float(name: str, value) -> float:
    """``value`` as a finite float; ValueError naming ``name`` otherwise (booleans are not numbers here)."""
    if isinstance(value, bool):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number, got {value!r}") from None
    if not np.isfinite(out):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return out


def state_index(value) -> int:
    """A state index: an integer >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"state_index must be an integer >= 0, got {value!r}")
    return int(value)
