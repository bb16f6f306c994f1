"""The reference side of IC-GN, computed once per reference and reused by every match of a sequence.

IC-GN's reference side (Pan, Li & Tong 2013) -- the subset's mean and norm, its Hessian ``H = sum J^T J``
inverted, ``sum J^T (f - f_m)`` and ``sum J^T`` -- depends on the reference image, the subset and the shape
function only. A stereo sequence correlates *one* left reference to the right reference and to both deformed
images of every state (the paper's scheme), so the same subsets are prepared 1 + 2 x states times. A
:class:`ReferenceCache` holds each grid node's record: the first match that reaches the node computes and writes
it, every later one reads it (and only copies the subset's values and gradients again). The results are the same
numbers as without the cache (the same functions on the same pixels).

A record belongs to one reference image, one grid and one set of settings: :meth:`ReferenceCache.check` refuses
any other (a cached Hessian of another image would converge IC-GN to wrong displacements without a sign).
Memory: ``(6 + np^2 + 2 np)`` float64 per grid node (np = 6 or 12 parameters): 1.4 kB at second order,
~110 MB for the paper's 80 000 nodes; twice that, and the transposed reference, once a column-major match
(:mod:`.traversal`) has used it.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from .icgn import INFO_FILLED, INFO_SIZE


def _fingerprint(values: np.ndarray) -> int:
    """CRC-32 of an image's bytes (NaN patterns included): equal images, equal fingerprint."""
    return zlib.crc32(np.ascontiguousarray(values).view(np.uint8).reshape(-1))


@dataclass(eq=False)
class ReferenceCache:
    """Reference-side records of every node of one POI grid on one reference image.

    Make it with :meth:`for_grid` and pass it to :func:`measurement.dic.correlate` (``reference_cache=``) for
    every match of the same reference; nodes are filled as they are first matched.

    Attributes
    ----------
    info : ndarray of float64, shape (R, C, INFO_SIZE)
        Per node: filled flag, status, delta_f, subset mean, SSSIG x and y (:data:`.icgn.INFO_SIZE`).
    hinv : ndarray of float64, shape (R, C, np, np)
        Inverse Hessian.
    a, s : ndarray of float64, shape (R, C, np)
        ``sum J^T (f - f_m)`` and ``sum J^T``.
    """

    info: np.ndarray
    hinv: np.ndarray
    a: np.ndarray
    s: np.ndarray
    grid_x: np.ndarray = field(repr=False)
    grid_y: np.ndarray = field(repr=False)
    subset_size: int
    order: int
    interpolation: str
    lowpass_sigma_px: float
    min_std: float
    fingerprint: int
    _values: np.ndarray = field(repr=False)
    _subset_status: np.ndarray | None = field(default=None, repr=False)
    _transposed: tuple | None = field(default=None, repr=False)

    @classmethod
    def for_grid(cls, reference_values: np.ndarray, grid, settings, min_std: float) -> "ReferenceCache":
        """An empty cache for ``grid`` (a :class:`.grid.PoiGrid`) on the prepared reference's ``values`` with
        ``settings`` (:class:`.correlate.DICSettings`) and the subset texture threshold ``min_std`` (grey)."""
        npar = 6 if settings.order == 1 else 12
        rows, cols = grid.shape
        info = np.zeros((rows, cols, INFO_SIZE))
        return cls(info, np.zeros((rows, cols, npar, npar)), np.zeros((rows, cols, npar)),
                   np.zeros((rows, cols, npar)), np.asarray(grid.x).copy(), np.asarray(grid.y).copy(),
                   int(settings.subset_size), int(settings.order), str(settings.interpolation),
                   float(settings.lowpass_sigma_px), float(min_std), _fingerprint(reference_values),
                   reference_values)

    @property
    def filled_fraction(self) -> float:
        """Share of the grid's nodes whose record is filled."""
        return float(np.mean(self.info[..., INFO_FILLED] != 0.0)) if self.info.size else 0.0

    def subset_status(self, compute) -> np.ndarray:
        """The reference-only status of every grid node (usable, out of the image, untextured, invalid), shape
        (R, C): ``compute(xs, ys)`` (the match's ``reference_subset_status`` on this reference) is called once, on
        every node, and its answer kept: it depends on the reference, grid and texture threshold only, which
        :meth:`check` guarantees (an integral-image pass over the reference that every match would repeat)."""
        if self._subset_status is None:
            status = compute(self.grid_x.reshape(-1), self.grid_y.reshape(-1))
            self._subset_status = np.asarray(status).reshape(self.grid_x.shape)
        return self._subset_status

    def transposed(self, make, grid_t, settings, min_std: float) -> tuple:
        """(values, grad_x, grad_y, cache) of this reference seen transposed, for column-major matches
        (:mod:`.traversal`): ``make()`` gives the three arrays, called once; the cache holds the records of the
        transposed grid ``grid_t`` (another parameter order, another summation order: not this cache's)."""
        if self._transposed is None:
            values_t, grad_x_t, grad_y_t = make()
            self._transposed = (values_t, grad_x_t, grad_y_t,
                                ReferenceCache.for_grid(values_t, grid_t, settings, min_std))
        self._transposed[3].check(self._transposed[0], grid_t, settings, min_std)
        return self._transposed

    def check(self, reference_values: np.ndarray, grid, settings, min_std: float) -> None:
        """Refuse a match this cache was not made for.

        Raises
        ------
        ValueError
            Naming what differs: the grid (shape or node positions), a setting (subset size, shape-function
            order, interpolation, low-pass, texture threshold) or the reference image.
        """
        differs = []
        if tuple(grid.shape) != self.info.shape[:2] or not (np.array_equal(grid.x, self.grid_x)
                                                            and np.array_equal(grid.y, self.grid_y)):
            differs.append("the grid of points of interest")
        for name, mine, theirs in (("subset_size", self.subset_size, int(settings.subset_size)),
                                   ("order", self.order, int(settings.order)),
                                   ("interpolation", self.interpolation, str(settings.interpolation)),
                                   ("lowpass_sigma_px", self.lowpass_sigma_px, float(settings.lowpass_sigma_px)),
                                   ("min_subset_std", self.min_std, float(min_std))):
            if mine != theirs:
                differs.append(f"{name} ({theirs!r}, the cache has {mine!r})")
        if reference_values is not self._values and (
                reference_values.shape != self._values.shape or _fingerprint(reference_values) != self.fingerprint):
            differs.append("the reference image")
        if differs:
            raise ValueError("reference_cache was made for another match: " + "; ".join(differs)
                             + ". Make one cache per reference image, grid and settings (ReferenceCache.for_grid).")


__all__ = ["ReferenceCache"]
