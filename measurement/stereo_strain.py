"""Surface strain of stereo-DIC states: the strain each result file carries, with its gauge and its sigma.

:func:`measurement.strain.surface_strain` on a state's grid of triangulated points (reference shape -> state),
with what a reader of VIC-3D or MatchID results expects beside the numbers:

* the **virtual strain gauge** in px (``(window - 1) * step + subset``, :func:`measurement.strain.virtual_strain_gauge_px`)
  and in mm on the specimen (the median distance between neighbouring grid points, per px of step, times the
  gauge in px), so a strain value says over what length of material it averages;
* the **principal strains** E1 >= E2 and the angle of E1;
* the **standard uncertainty** of E11, E22, E12 from the images' noise (strain window only,
  :mod:`measurement.uncertainty.strain`), NaN where the shape carries no uncertainty.

Conventions: Green-Lagrange strain (dimensionless, tensor shear ``E12``: half the engineering shear), in the
reference surface's local frame of :mod:`measurement.strain` (``e1`` = the grid's column direction, i.e. the left
image's x axis, projected onto the tangent plane; ``e2 = n x e1``, close to the image's y axis). Green-Lagrange
strain is unchanged by a rigid motion, so no rigid motion is removed first.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measurement.strain import TRIANGLE_GAUGE_WINDOW, surface_strain, virtual_strain_gauge_px

#: What every strain this module writes is, stated once (result files, manifests, the formats page).
STRAIN_CONVENTION = {"measure": "green-lagrange", "shear": "tensor", "unit": "1",
                     "frame": "reference surface: e1 = left image x (grid columns) projected onto the tangent plane, "
                              "e2 = n x e1 (close to image y), n = e1 x e2 pointing away from the left camera"}


@dataclass(frozen=True)
class StrainSettings:
    """How strain is computed from a grid of points.

    Attributes
    ----------
    window : int or None
        Strain window in grid points per side (odd, >= 3); None: the paper's triangles (Cosserat point elements).
    fit : {"linear", "quadratic"}
        Order of the window's displacement fit.
    """

    window: int | None = 9
    fit: str = "linear"

    def __post_init__(self):
        w = self.window
        if w is not None and (isinstance(w, bool) or not isinstance(w, (int, np.integer)) or w < 3 or w % 2 == 0):
            raise ValueError(f"strain window must be an odd number of grid points >= 3 (or None for triangles), "
                             f"got {w!r}")
        if self.fit not in ("linear", "quadratic"):
            raise ValueError(f"strain fit must be 'linear' or 'quadratic', got {self.fit!r}")
        if w is None and self.fit != "linear":
            raise ValueError("a quadratic strain fit needs a strain window (the triangles have no fit)")

    @property
    def method(self) -> str:
        return "triangle" if self.window is None else "window"

    @property
    def gauge_points(self) -> int:
        """Grid points per side of one strain value's support."""
        return TRIANGLE_GAUGE_WINDOW if self.window is None else int(self.window)


@dataclass(frozen=True)
class StateStrain:
    """Strain of one state at the shape's points (arrays (N,), the order of ``shape.x``; NaN where undefined).

    Attributes
    ----------
    E11, E22, E12 : Green-Lagrange strain in the local frame (module notes), dimensionless
    E1, E2 : principal strains, E1 >= E2
    angle_deg : angle of E1 from e1 towards e2, degrees, (-90, 90]
    sigma : (N, 3) standard uncertainty of E11, E22, E12 from the images' noise, or None (triangles, or a shape
        without uncertainty)
    settings : StrainSettings
    gauge_px : the virtual strain gauge in the left image, px
    gauge_mm : the same on the specimen, mm (median grid spacing in mm per px of step times ``gauge_px``)
    """

    E11: np.ndarray
    E22: np.ndarray
    E12: np.ndarray
    E1: np.ndarray
    E2: np.ndarray
    angle_deg: np.ndarray
    sigma: np.ndarray | None
    settings: StrainSettings
    gauge_px: float
    gauge_mm: float


def on_grid(values: np.ndarray, grid) -> np.ndarray:
    """Per-point values (N, ...) of a grid's active nodes laid out as the grid (rows, cols, ...), NaN elsewhere."""
    out = np.full(grid.shape + values.shape[1:], np.nan)
    out[grid.active] = values
    return out


def mm_per_px(shape) -> float:
    """Median distance between measured neighbouring grid points of the reference shape per px of grid step, mm/px."""
    grid = shape.grid
    X = on_grid(np.where(shape.valid[:, None], shape.X_mm, np.nan), grid)
    steps = [np.linalg.norm(X[:, 1:] - X[:, :-1], axis=-1), np.linalg.norm(X[1:] - X[:-1], axis=-1)]
    d = np.concatenate([s[np.isfinite(s)] for s in steps])
    if d.size == 0:
        raise ValueError("no two neighbouring grid points are measured: the strain gauge has no length in mm")
    return float(np.median(d)) / float(grid.step)


class SequenceStrain:
    """What the strain of every state of one reference shape shares: the settings, the gauge, and the noise
    correlations of neighbouring points (:func:`measurement.uncertainty.strain.pair_covariances`, once).

    Parameters
    ----------
    shape : measurement.stereo_dic.StereoShape
    cameras : (left, right, R_right_from_left, T_right_from_left_mm) the rig the shape was triangulated with
    settings : StrainSettings
    """

    def __init__(self, shape, cameras, settings: StrainSettings = StrainSettings()):
        self.shape, self.cameras, self.settings = shape, tuple(cameras), settings
        grid = shape.grid
        self.gauge_px = virtual_strain_gauge_px(settings.gauge_points, grid.step, grid.subset_size)
        self.gauge_mm = self.gauge_px * mm_per_px(shape)
        self._pairs = self._G_ref = None
        self.has_sigma = settings.window is not None and shape.subsets is not None and shape.match_uncertainty is not None

    def _sigma_inputs(self):
        if self._pairs is None:
            from measurement.uncertainty.stereo import triangulation_sensitivity
            from measurement.uncertainty.strain import pair_covariances

            grid = self.shape.grid
            self._pairs = pair_covariances(self.shape.reference, self.shape.subsets, self.shape.right_match.grid_index,
                                           grid.shape, grid.step, window=self.settings.window)
            self._G_ref = triangulation_sensitivity(*self.cameras, self.shape.X_mm)
        return self._pairs, self._G_ref

    def state(self, state) -> StateStrain:
        """The strain of ``state`` (a :class:`measurement.stereo_dic.StereoState` of this shape)."""
        shape, grid = self.shape, self.shape.grid
        ok = shape.valid & state.valid
        nan3 = np.full((shape.x.size, 3), np.nan)
        strain = surface_strain(on_grid(np.where(ok[:, None], shape.X_mm, nan3), grid),
                                on_grid(np.where(ok[:, None], state.X_mm, nan3), grid),
                                window=self.settings.window, fit=self.settings.fit)
        sigma = None
        if self.has_sigma and state.left_uncertainty is not None and state.right_uncertainty is not None:
            from measurement.uncertainty.stereo import triangulation_sensitivity
            from measurement.uncertainty.strain import state_strain_sigma

            pairs, G_ref = self._sigma_inputs()
            G_def = triangulation_sensitivity(*self.cameras, state.X_mm)
            sigma = state_strain_sigma(shape, state, strain, G_ref, G_def, pairs)[grid.active]
            sigma[~np.isfinite(strain.E11[grid.active])] = np.nan
        active = grid.active
        return StateStrain(strain.E11[active], strain.E22[active], strain.E12[active], strain.E1[active],
                           strain.E2[active], strain.angle_deg[active], sigma, self.settings, self.gauge_px,
                           self.gauge_mm)

    def reference(self) -> StateStrain:
        """The reference shape against itself: zero strain (and zero sigma) wherever a point is measured."""
        n = self.shape.x.size
        zero = np.where(self.shape.valid, 0.0, np.nan)
        sigma = np.repeat(zero[:, None], 3, axis=1) if self.has_sigma else None
        return StateStrain(zero, zero.copy(), zero.copy(), zero.copy(), zero.copy(), np.where(self.shape.valid, 0.0,
                                                                                               np.nan) * np.ones(n),
                           sigma, self.settings, self.gauge_px, self.gauge_mm)

    def description(self) -> dict:
        """The strain's settings, gauge and convention as a manifest records them."""
        return {**STRAIN_CONVENTION, "method": self.settings.method, "window_points": self.settings.window,
                "fit": self.settings.fit if self.settings.window is not None else None,
                "gauge_px": self.gauge_px, "gauge_mm": self.gauge_mm, "sigma": self.has_sigma}
