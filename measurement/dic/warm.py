"""Compile (or load from numba's disk cache) every DIC kernel once, before timed or parallel work.

A fresh process pays numba's compilation on its first :func:`~measurement.dic.correlate` call (about 20 s on
2 cores with an empty cache, 1–3 s loading a warm cache). A study worker that warms up first keeps that cost
out of its first case's timing and lets a progress line say what the wait is.
"""
from __future__ import annotations

import time

import numpy as np
from scipy import ndimage


def warm_up_kernels(orders=(1, 2), interpolations=("biquintic", "bicubic")) -> float:
    """Run a tiny correlation (a 64 px smoothed-noise pair shifted by 0.3 px) with every shape-function order and
    interpolant given, so that every kernel the package uses is compiled or loaded; returns the seconds taken."""
    from .correlate import DICSettings, correlate

    start = time.perf_counter()
    rng = np.random.default_rng(0)
    texture = ndimage.gaussian_filter(rng.normal(size=(72, 72)), 1.5)
    texture = 128.0 + 40.0 * texture / texture.std()
    reference = texture[4:68, 4:68]
    deformed = ndimage.shift(texture, (0.0, 0.3), order=3, mode="nearest")[4:68, 4:68]
    for order in orders:
        for interpolation in interpolations:
            settings = DICSettings(subset_size=15, step=8, order=order, interpolation=interpolation)
            correlate(reference, deformed, settings, roi=(16, 16, 47, 47))
    return time.perf_counter() - start


if __name__ == "__main__":
    # ``python -m measurement.dic.warm``: fill numba's on-disk cache from a separate process (a long job can start
    # this beside work that does not need the kernels yet, and find them compiled when it does)
    print(f"DIC kernels ready in {warm_up_kernels():.1f} s")
