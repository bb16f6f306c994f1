"""Timing helper shared by the benchmark scripts (run as ``python benchmarks/NAME.py``: this folder is on the path)."""
from __future__ import annotations

import time


def best_of(fn, repeat: int = 2):
    """``(seconds, result)``: the shortest of ``repeat`` calls of ``fn()`` (``time.perf_counter``) and the last
    result."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out
