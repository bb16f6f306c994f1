"""Column-major IC-GN (measurement/dic/traversal.py): a foreshortened match sampled column by column gives the
analytic field's twelve shape parameters, the row-major match's numbers to IC-GN's tolerance, and the same
numbers with and without a reference cache."""
from __future__ import annotations

import numpy as np
import pytest

from measurement.dic import DICSettings, ReferenceCache, Seed, correlate, poi_grid
from measurement.dic.correlate import prepare_image, subset_min_std
from measurement.dic.traversal import (
    TRANSPOSED_PARAMETERS,
    choose_traversal,
    transposed_grid,
)
from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle

SHAPE = (256, 256)
CENTRE = (128.0, 128.0)
SETTINGS = DICSettings(subset_size=41, step=12, order=2)
ROI = (50, 50, 206, 206)


class _Foreshortened:
    """u = u0 + ux dx + uy dy + uxx dx^2 / 2 + uxy dx dy + uyy dy^2 / 2 (v likewise) about the image centre: all
    twelve shape parameters non-zero and different, with a stereo view's compression along x (u_x = -0.07)."""

    U = (2.3, -0.07, 0.011, 2.0e-4, -1.2e-4, 0.8e-4)
    V = (-1.4, -0.012, 0.014, -0.6e-4, 1.6e-4, -2.2e-4)

    @staticmethod
    def _one(c, dx, dy):
        return c[0] + c[1] * dx + c[2] * dy + 0.5 * c[3] * dx * dx + c[4] * dx * dy + 0.5 * c[5] * dy * dy

    def __call__(self, X, Y):
        dx, dy = np.asarray(X, float) - CENTRE[0], np.asarray(Y, float) - CENTRE[1]
        return self._one(self.U, dx, dy), self._one(self.V, dx, dy)

    def gradient(self, X, Y):
        dx, dy = np.asarray(X, float) - CENTRE[0], np.asarray(Y, float) - CENTRE[1]
        (_, ux, uy, uxx, uxy, uyy), (_, vx, vy, vxx, vxy, vyy) = self.U, self.V
        return (ux + uxx * dx + uxy * dy, uy + uxy * dx + uyy * dy, vx + vxx * dx + vxy * dy,
                vy + vxy * dx + vyy * dy)

    def parameters(self, X, Y):
        """The exact second-order shape parameters at reference points (X, Y): (N, 12)."""
        X, Y = np.asarray(X, float), np.asarray(Y, float)
        u, v = self(X, Y)
        ux, uy, vx, vy = self.gradient(X, Y)
        ones = np.ones_like(X)
        return np.column_stack([u, ux, uy, self.U[3] * ones, self.U[4] * ones, self.U[5] * ones,
                                v, vx, vy, self.V[3] * ones, self.V[4] * ones, self.V[5] * ones])


@pytest.fixture(scope="module")
def foreshortened():
    field = _Foreshortened()
    pattern = gaussian_speckle(extent_for_shape(SHAPE, margin_px=60), 1.8, seed=11)
    reference, deformed = pattern.render_reference(SHAPE), pattern.render_deformed(SHAPE, field)
    grid = poi_grid(SHAPE, SETTINGS.subset_size, SETTINGS.step, roi=ROI)
    middle = grid.shape[0] // 2
    xs, ys = grid.x[middle][grid.active[middle]], grid.y[middle][grid.active[middle]]
    truth = field.parameters(xs, ys)
    seeds = [Seed(int(x), int(y), p) for x, y, p in zip(xs, ys, truth)]
    return field, reference, deformed, grid, seeds


def test_the_transposed_parameter_order_is_its_own_inverse_and_swaps_x_and_y():
    names = ("u", "ux", "uy", "uxx", "uxy", "uyy", "v", "vx", "vy", "vxx", "vxy", "vyy")
    swapped = {"u": "v", "x": "y", "y": "x", "v": "u"}
    expected = ["".join(swapped[ch] for ch in name) for name in names]
    expected = [e[0] + "".join(sorted(e[1:])) for e in expected]       # vyx -> vxy
    assert [names[k] for k in TRANSPOSED_PARAMETERS] == expected
    assert np.array_equal(TRANSPOSED_PARAMETERS[TRANSPOSED_PARAMETERS], np.arange(12))


def test_auto_traversal_takes_columns_for_a_foreshortened_warp_and_rows_otherwise(foreshortened):
    _, reference, deformed, grid, seeds = foreshortened
    p = np.array([s.parameters for s in seeds])
    assert choose_traversal("auto", p, 20) == "columns"
    assert choose_traversal("auto", p[:, TRANSPOSED_PARAMETERS], 20) == "rows"     # the same warp turned
    assert choose_traversal("auto", np.zeros((3, 12)), 20) == "rows"               # translation seeds
    assert correlate(reference, deformed, SETTINGS, grid=grid, seeds=seeds).traversal == "columns"
    with pytest.raises(ValueError, match="traversal must be one of auto, rows, columns, got 'diagonal'"):
        correlate(reference, deformed, SETTINGS, grid=grid, seeds=seeds, traversal="diagonal")


def test_columns_give_the_analytic_shape_parameters_and_the_rows_numbers(foreshortened):
    """Every one of the twelve parameters against the analytic field (a parameter put back in the wrong slot, or
    a SSSIG axis left swapped, fails here), and the row-major match to 2 x IC-GN's tolerance."""
    field, reference, deformed, grid, seeds = foreshortened
    columns = correlate(reference, deformed, SETTINGS, grid=grid, seeds=seeds, traversal="columns")
    rows = correlate(reference, deformed, SETTINGS, grid=grid, seeds=seeds, traversal="rows")
    assert columns.traversal == "columns" and rows.traversal == "rows"
    assert columns.converged.all() and rows.converged.all(), (columns.status_counts(), rows.status_counts())
    truth = field.parameters(columns.x, columns.y)
    error = np.abs(columns.parameters - truth)
    assert error[:, [0, 6]].max() < 3e-3                       # u, v, px
    assert error[:, [1, 2, 7, 8]].max() < 3e-4                 # gradients
    assert error[:, [3, 4, 5, 9, 10, 11]].max() < 3e-5         # second order, 1/px
    assert np.abs(columns.parameters[:, [0, 6]] - rows.parameters[:, [0, 6]]).max() <= 2 * SETTINGS.tolerance_px
    assert np.abs(columns.zncc - rows.zncc).max() < 1e-6
    assert np.allclose(columns.sssig, rows.sssig, rtol=1e-9)
    assert not np.allclose(columns.sssig[:, 0], columns.sssig[:, 1], rtol=1e-3)   # the check above can see a swap


def test_a_column_match_reads_its_own_cached_reference_and_gives_the_same_numbers(foreshortened):
    """With a reference cache the transposed reference and its records are made once and read afterwards: the
    same numbers as without the cache to 1e-12; the row-major records are not touched."""
    _, reference, deformed, grid, seeds = foreshortened
    prepared = prepare_image(reference, SETTINGS.interpolation, True, "reference")
    cache = ReferenceCache.for_grid(prepared.values, grid, SETTINGS, subset_min_std(SETTINGS, prepared.values))
    fresh = correlate(prepared, deformed, SETTINGS, grid=grid, seeds=seeds, traversal="columns")
    first = correlate(prepared, deformed, SETTINGS, grid=grid, seeds=seeds, traversal="columns", reference_cache=cache)
    second = correlate(prepared, deformed, SETTINGS, grid=grid, seeds=seeds, traversal="columns",
                       reference_cache=cache)
    transposed = cache.transposed(None, transposed_grid(grid), SETTINGS, cache.min_std)[3]   # made: no make()
    assert cache.filled_fraction == 0.0 and transposed.filled_fraction > 0.9
    for result in (first, second):
        assert np.array_equal(result.status, fresh.status)
        assert np.max(np.abs(result.parameters - fresh.parameters)) <= 1e-12
        assert np.max(np.abs(result.zncc - fresh.zncc)) <= 1e-12
