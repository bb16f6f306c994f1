"""Strain conventions of DIC tools, and their conversion to this project's: Green-Lagrange, tensor shear,
dimensionless.

A result file's strain columns are numbers whose meaning the file seldom states: VIC-3D writes Lagrange strain by
default but offers engineering, Hencky and Euler-Almansi strain under the same column names; shear may be the tensor
component or the engineering shear (twice it); values may be dimensionless, in % or in µε. A reader never guesses:
where the file does not say, the user states it (:class:`StrainConvention`, the ``--strain-*`` options), else the
strain is refused (:class:`UnstatedStrainError`).

Conversions are exact for the principal values of a 2 x 2 strain tensor (each measure is a function of the
principal stretch ``lambda``):

* ``green-lagrange``: ``E = (lambda^2 - 1) / 2``;
* ``engineering`` (Biot, ``lambda - 1``): ``E = ((1 + e)^2 - 1) / 2``;
* ``cauchy`` (the small strain, the symmetric displacement gradient): as Biot's, to which it is equal where the
  material does not rotate;
* ``hencky`` (logarithmic, ``ln lambda``): ``E = (exp(2 h) - 1) / 2``;
* ``euler-almansi`` (``(1 - lambda^-2) / 2``): ``E = e / (1 - 2 e)``.

Green-Lagrange, Biot and Hencky strain share their principal directions (all are functions of the right stretch
U); Euler-Almansi strain is a function of the left stretch V = R U R^T, whose directions are turned by the rotation
R: its conversion keeps the directions, which is exact where the material does not rotate in the surface plane and
wrong by second order in the rotation otherwise (a few µε at 1 mrad and 1 % strain). The small (Cauchy) strain
differs from Biot's by the same order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MEASURES = ("green-lagrange", "engineering", "cauchy", "hencky", "euler-almansi")
SHEARS = ("tensor", "engineering")
#: Units of strain values: what one unit is, dimensionless.
UNITS = {"1": 1.0, "%": 1e-2, "microstrain": 1e-6}


class UnstatedStrainError(ValueError):
    """A file holds strain whose convention it does not state, and the user did not state it either."""


@dataclass(frozen=True)
class StrainConvention:
    """What a tool's strain columns are: ``measure`` (:data:`MEASURES`), ``shear`` (:data:`SHEARS`: the xy column
    is the tensor component or the engineering shear, twice it) and ``unit`` (:data:`UNITS`)."""

    measure: str = "green-lagrange"
    shear: str = "tensor"
    unit: str = "1"

    def __post_init__(self):
        for name, value, allowed in (("measure", self.measure, MEASURES), ("shear", self.shear, SHEARS),
                                     ("unit", self.unit, tuple(UNITS))):
            if value not in allowed:
                raise ValueError(f"strain {name} {value!r}: choose one of {', '.join(allowed)}")

    def text(self) -> str:
        return f"{self.measure}, {self.shear} shear, unit {self.unit}"


def convention_from_options(measure: str | None, shear: str | None, unit: str | None) -> StrainConvention | None:
    """The convention the ``--strain-measure``/``--strain-shear``/``--strain-unit`` options state, None when none is
    given; all three or none (a half-stated convention is refused)."""
    given = {"--strain-measure": measure, "--strain-shear": shear, "--strain-unit": unit}
    if all(v is None for v in given.values()):
        return None
    missing = [k for k, v in given.items() if v is None]
    if missing:
        raise ValueError(f"state the whole strain convention: {', '.join(missing)} missing (beside "
                         f"{', '.join(k for k, v in given.items() if v is not None)})")
    return StrainConvention(measure, shear, unit)


def to_green_lagrange(exx, eyy, exy, convention: StrainConvention) -> np.ndarray:
    """(N, 3) Green-Lagrange E11, E22, E12 (tensor shear, dimensionless) from a tool's exx, eyy, exy (N,) in
    ``convention``; NaN stays NaN."""
    scale = UNITS[convention.unit]
    a = np.asarray(exx, float) * scale
    b = np.asarray(eyy, float) * scale
    c = np.asarray(exy, float) * scale * (0.5 if convention.shear == "engineering" else 1.0)
    if convention.measure == "green-lagrange":
        return np.column_stack([a, b, c])
    # principal values and direction of the 2 x 2 tensor [[a, c], [c, b]], converted value by value
    mean, radius = 0.5 * (a + b), np.hypot(0.5 * (a - b), c)
    theta = 0.5 * np.arctan2(2.0 * c, a - b)
    p1, p2 = mean + radius, mean - radius
    biot = lambda e: 0.5 * ((1.0 + e) ** 2 - 1.0)  # noqa: E731
    f = {"engineering": biot, "cauchy": biot,
         "hencky": lambda h: 0.5 * np.expm1(2.0 * h),
         "euler-almansi": lambda e: e / (1.0 - 2.0 * e)}[convention.measure]
    with np.errstate(invalid="ignore", divide="ignore"):
        q1, q2 = f(p1), f(p2)
    cos, sin = np.cos(theta), np.sin(theta)
    return np.column_stack([q1 * cos ** 2 + q2 * sin ** 2, q1 * sin ** 2 + q2 * cos ** 2, (q1 - q2) * sin * cos])


def check_shear(path, exx, eyy, exy, e1, e2, convention: StrainConvention, names: str) -> None:
    """Where a file also holds its principal strains, check that the stated shear convention reproduces them.

    The principal values of ``[[exx, s exy], [s exy, eyy]]`` are the file's ``e1, e2`` for the right ``s`` (1 for
    tensor shear, 1/2 for engineering shear), whatever the strain measure (the principal values of one tensor).
    Raises ValueError naming the file and the convention the columns do follow when the stated one does not (by
    more than 1 % of the strain's size, over the median of the points).
    """
    values = [np.asarray(a, float) for a in (exx, eyy, exy, e1, e2)]
    ok = np.all([np.isfinite(v) for v in values], axis=0)
    if ok.sum() < 3:
        return
    a, b, c, p1, p2 = (v[ok] for v in values)
    size = np.median(np.abs(np.concatenate([p1, p2]))) + 1e-300

    def misfit(half: float) -> float:
        mean, radius = 0.5 * (a + b), np.hypot(0.5 * (a - b), half * c)
        return float(np.median(np.abs(mean + radius - p1) + np.abs(mean - radius - p2))) / size

    stated = 0.5 if convention.shear == "engineering" else 1.0
    other = 1.0 if stated == 0.5 else 0.5
    if misfit(stated) > 1e-2 and misfit(other) < misfit(stated):
        follows = "tensor" if other == 1.0 else "engineering"
        raise ValueError(f"{path}: --strain-shear {convention.shear}, but the file's principal strains ({names}) are "
                         f"those of {follows} shear (median misfit {100 * misfit(stated):.3g} % of the strain with "
                         f"{convention.shear} shear, {100 * misfit(other):.3g} % with {follows})")
