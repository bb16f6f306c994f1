"""Argument checks shared across the truth side's rooms (one wording for every module's messages)."""
from __future__ import annotations

import math

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


def finite_number(name: str, value) -> float:
    """``value`` as a float, or ValueError naming the parameter when it is not a finite number.

    Stricter than :func:`finite_float`: strings are refused too (a target's config typo must not turn into a
    plausible number)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return v


def is_int(value) -> bool:
    """Whether ``value`` is an integer (numpy's included), booleans excluded."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
