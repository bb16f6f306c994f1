"""Keep freed memory in the process for reuse instead of handing large blocks back to the kernel (glibc).

glibc's malloc serves every block above its mmap threshold (32 MiB at most) with a fresh ``mmap`` and unmaps it
when it is freed, so each 5 MP float64 image (40 MB) and each of its temporaries is new memory: the kernel zeroes
and maps it one 4 KiB page fault at a time. One full-resolution case of the Fig 6 study (30 board and 11 stage
renders per camera, calibration, stereo DIC) faulted 9.8 M times and spent 33 s in the kernel for 106 s of user
time. With glibc told not to use ``mmap`` for blocks and not to trim its heap, a freed image's pages are reused:
0.5 M faults, 6 s in the kernel, the case 2:02 -> 1:41 (``workbench sweep``, 1 worker); its peak resident memory
1.5 -> 1.9 GB, since freed blocks stay mapped for the next allocation.

:func:`keep_freed_memory` sets this for the running process (``mallopt``) and, through the environment glibc reads
at start-up, for the processes it starts (Dask workers). ``WORKBENCH_KEEP_FREED_MEMORY=0`` leaves malloc as it is.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os

#: glibc's mallopt parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_MAX = -4

#: Bytes of free memory at the top of the heap kept rather than returned (the largest value mallopt takes).
TRIM_THRESHOLD_BYTES = 2**31 - 1

#: What glibc reads at start-up in a child process.
ENVIRONMENT = {"MALLOC_MMAP_MAX_": "0", "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD_BYTES)}

#: Set to "0" to leave malloc's defaults.
SWITCH = "WORKBENCH_KEEP_FREED_MEMORY"


def keep_freed_memory() -> bool:
    """Make glibc keep freed blocks for reuse, in this process and the ones it starts.

    Returns
    -------
    bool
        True if set; False where it does not apply (``WORKBENCH_KEEP_FREED_MEMORY=0``, or a C library without
        glibc's ``mallopt``): nothing changed then.
    """
    if os.environ.get(SWITCH, "1") == "0":
        return False
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    if not (mallopt(M_MMAP_MAX, 0) == 1 and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1):
        return False
    os.environ.update(ENVIRONMENT)
    return True


__all__ = ["ENVIRONMENT", "SWITCH", "keep_freed_memory"]
