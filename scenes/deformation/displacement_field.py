"""Displacement fields of a specimen (truth side): the interface every field implements, and the simple ones.

Every field is a :class:`DisplacementField`: ``u(X)`` in the specimen frame (mm; for the beam of
:class:`scenes.specimens.beam.BendingSpecimen`: origin at the centre of the speckled front face, x along the
length, y along the height pointing DOWN, z into the material, front face ``z = 0``). A field is also a plain
callable (``field(X)`` is the displacement), which is what ``BendingSpecimen.surfaces(displacement_mm=...)`` takes.

* :class:`RigidMotionField`, :class:`ScaledField` (a load state = unit-load solution x load, linear
  elasticity), :class:`DifferenceField` (a state relative to a preloaded reference).
* :func:`as_points`, :func:`raise_outside`, :func:`field_contains`: the checks every field shares (one wording).

The beam's finite-element solution is :mod:`scenes.deformation.beam_bending`; a user's FE result is read by
:mod:`scenes.specimens.fe_files` (the generic specimen path).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["DisplacementField", "SupportsDisplacementField", "RigidMotionField", "ScaledField", "DifferenceField",
           "as_points", "raise_outside", "field_contains"]



# ------------------------------------------------------------------------------------------------------------
# Points and domain errors
def as_points(X, name: str = "X_specimen_mm") -> np.ndarray:
    """Validated (N, 3) float64 copy-free view of ``X``."""
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"{name} must be (N, 3) in mm, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name} must be finite")
    return X


def _bbox_text(X: np.ndarray) -> str:
    lo, hi = X.min(axis=0), X.max(axis=0)
    return ", ".join(f"{c} in [{a:.6g}, {b:.6g}] mm" for c, a, b in zip("xyz", lo, hi))


def raise_outside(X: np.ndarray, inside: np.ndarray, domain: str) -> None:
    """ValueError naming how many points lie outside ``domain`` and their bounding box."""
    out = ~inside
    n = int(out.sum())
    if n:
        raise ValueError(f"{n} of {len(X)} points lie outside {domain}; their bounding box: {_bbox_text(X[out])}")


# ------------------------------------------------------------------------------------------------------------
# The interface
@runtime_checkable
class SupportsDisplacementField(Protocol):
    """Anything with ``displacement_mm(X (N, 3)) -> (N, 3)`` and ``gradient(X (N, 3)) -> (N, 3, 3)``."""

    def displacement_mm(self, X_specimen_mm: np.ndarray) -> np.ndarray: ...

    def gradient(self, X_specimen_mm: np.ndarray) -> np.ndarray: ...


class DisplacementField(ABC):
    """A displacement field u(X) in the specimen frame (mm).

    Subclasses implement :meth:`displacement_mm` and :meth:`gradient`; points outside the field's domain
    raise a ValueError naming how many points and their bounding box. ``field(X)`` is
    ``field.displacement_mm(X)``, so a field can be passed wherever a callable ``u(X) -> (N, 3)`` is expected.
    """

    def __call__(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        return self.displacement_mm(X_specimen_mm)

    @abstractmethod
    def displacement_mm(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """Displacement u at material points.

        Parameters
        ----------
        X_specimen_mm : (N, 3) float, mm, specimen frame (undeformed positions)

        Returns
        -------
        (N, 3) float, mm
        """

    @abstractmethod
    def gradient(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """Displacement gradient ``H[n, i, j] = du_i / dX_j`` (dimensionless), (N, 3, 3)."""

    def contains(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """(N,) bool: which points lie in the field's domain (default: everywhere)."""
        return np.ones(len(as_points(X_specimen_mm)), dtype=bool)

    def green_lagrange(self, X_specimen_mm: np.ndarray) -> np.ndarray:
        """Green-Lagrange strain ``E = (H + H^T + H^T H) / 2`` from :meth:`gradient`, (N, 3, 3), dimensionless."""
        H = self.gradient(X_specimen_mm)
        return 0.5 * (H + np.swapaxes(H, 1, 2) + np.einsum("nki,nkj->nij", H, H))


def field_contains(field, X: np.ndarray) -> np.ndarray:
    """``field.contains`` where the field has one; a plain duck-typed field is taken as defined everywhere."""
    fn = getattr(field, "contains", None)
    return np.asarray(fn(X), dtype=bool) if fn is not None else np.ones(len(X), dtype=bool)


@dataclass(frozen=True, eq=False)
class RigidMotionField(DisplacementField):
    """A rigid motion ``X -> R (X - c) + c + t``: ``u = R (X - c) + c + t - X``, gradient ``R - I``.

    Parameters
    ----------
    R : (3, 3) proper rotation
    t_mm : (3,) translation, mm
    centre_mm : (3,) centre of rotation, mm (default the origin)
    """

    R: np.ndarray
    t_mm: np.ndarray
    centre_mm: np.ndarray = (0.0, 0.0, 0.0)

    def __post_init__(self):
        R = np.array(self.R, dtype=float)
        t = np.array(self.t_mm, dtype=float).reshape(-1)
        c = np.array(self.centre_mm, dtype=float).reshape(-1)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("R must be a (3, 3) proper rotation matrix")
        if t.shape != (3,) or c.shape != (3,) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(c))):
            raise ValueError("t_mm and centre_mm must be finite 3-vectors in mm")
        for name, value in (("R", R), ("t_mm", t), ("centre_mm", c)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    def displacement_mm(self, X_specimen_mm):
        X = as_points(X_specimen_mm)
        return (X - self.centre_mm) @ self.R.T + self.centre_mm + self.t_mm - X

    def gradient(self, X_specimen_mm):
        X = as_points(X_specimen_mm)
        return np.broadcast_to(self.R - np.eye(3), (len(X), 3, 3)).copy()


@dataclass(frozen=True, eq=False)
class ScaledField(DisplacementField):
    """``factor * u_base``: in linear elasticity a load state is the unit-load solution times the load."""

    base: SupportsDisplacementField
    factor: float

    def __post_init__(self):
        if not np.isfinite(self.factor):
            raise ValueError(f"factor must be finite, got {self.factor}")

    def displacement_mm(self, X_specimen_mm):
        return self.factor * np.asarray(self.base.displacement_mm(as_points(X_specimen_mm)), dtype=float)

    def gradient(self, X_specimen_mm):
        return self.factor * np.asarray(self.base.gradient(as_points(X_specimen_mm)), dtype=float)

    def contains(self, X_specimen_mm):
        return field_contains(self.base, as_points(X_specimen_mm))


@dataclass(frozen=True, eq=False)
class DifferenceField(DisplacementField):
    """``u_a - u_b``: the truth of a state relative to a (preloaded) reference state, to first order."""

    a: SupportsDisplacementField
    b: SupportsDisplacementField

    def displacement_mm(self, X_specimen_mm):
        X = as_points(X_specimen_mm)
        return np.asarray(self.a.displacement_mm(X), float) - np.asarray(self.b.displacement_mm(X), float)

    def gradient(self, X_specimen_mm):
        X = as_points(X_specimen_mm)
        return np.asarray(self.a.gradient(X), float) - np.asarray(self.b.gradient(X), float)

    def contains(self, X_specimen_mm):
        X = as_points(X_specimen_mm)
        return field_contains(self.a, X) & field_contains(self.b, X)
