"""Subset-based 2-D digital image correlation (the paper's §3): ZNSSD, IC-GN with first- or second-order
shape functions, bicubic/biquintic B-spline interpolation, seeds by ZNCC search and reliability-guided
propagation. One module per algorithm:

- :mod:`.bspline` — prefilter and evaluation of the interpolant;
- :mod:`.shape_functions` — warps and their inverse composition;
- :mod:`.icgn` — the IC-GN iteration for one subset, and a parallel batch;
- :mod:`.initial` — ZNCC search for seeds (with rotations), the :class:`Seed` other guessers produce;
- :mod:`.guide` — reliability-guided propagation over the POI grid;
- :mod:`.reference_cache` — the reference side of IC-GN kept for every match of one reference;
- :mod:`.grid` — POIs from ROI, mask, subset and step;
- :mod:`.correlate` — the entry point :func:`correlate` and :class:`DICResult`.

numba's on-disk cache of these kernels is keyed on the sources of the whole package (:mod:`._numba_cache`,
imported first, before any kernel is defined): an edit in any module recompiles every kernel that might
inline it.
"""
from . import _numba_cache  # noqa: F401  (must precede the modules that define kernels)
from .correlate import DICResult, DICSettings, correlate
from .grid import PoiGrid, poi_grid
from .initial import Seed
from .reference_cache import ReferenceCache
from .shape_functions import PARAMETER_NAMES
from .status import Status

__all__ = ["DICResult", "DICSettings", "PARAMETER_NAMES", "PoiGrid", "ReferenceCache", "Seed", "Status", "correlate", "poi_grid"]
