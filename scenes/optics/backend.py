"""Choose and start the Mitsuba variant; the only module that decides how Mitsuba/Dr.Jit are loaded.

* A usable CUDA GPU -> ``cuda_ad_mono``; otherwise ``llvm_ad_mono`` (grey images either way).
* Dr.Jit's LLVM backend loads a shared libLLVM at run time. drjit 1.5.0 aborts the *whole process* inside
  LLVM 14-16 (``Cannot select ... fminimum``), so we never let it auto-detect: we point
  ``DRJIT_LIBLLVM_PATH`` at LLVM >= 19 before drjit is imported, and stop with a clear message when none
  exists. ``scripts/bootstrap.sh`` installs Debian's ``libllvm19``.
* ``WORKBENCH_VARIANT`` overrides the choice (e.g. ``llvm_ad_mono`` on a GPU machine).
* ``WORKBENCH_RENDER_THREADS`` caps Dr.Jit's CPU thread pool (a study's process workers use one each, so
  two workers on two cores do not fight over four threads).

Import ``mi``/``dr`` from here, never ``mitsuba`` directly: the variant must be set before any module that
subclasses Mitsuba types is imported.
"""
from __future__ import annotations

import ctypes
import glob
import os
import re

#: LLVM major versions known to work with drjit 1.5.0 (19 verified; newer ones accepted, preferred after 19).
_MIN_LLVM_MAJOR = 19

_LLVM_PATTERNS = (
    "/usr/lib/llvm-{v}/lib/libLLVM*.so*",
    "/usr/lib/*-linux-gnu/libLLVM-{v}*.so*",
    "/usr/lib/*-linux-gnu/libLLVM.so.{v}*",
    "/usr/lib64/libLLVM-{v}*.so*",
    "/usr/lib64/libLLVM.so.{v}*",
    "/usr/local/lib/libLLVM-{v}*.so*",
    "/opt/homebrew/opt/llvm@{v}/lib/libLLVM.dylib",
)


class BackendError(RuntimeError):
    """Mitsuba/Dr.Jit cannot run on this machine; the message says what to install."""


def _llvm_major(path: str) -> int | None:
    m = re.search(r"(?:llvm-|libLLVM-|libLLVM\.so\.|llvm@)(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm() -> str | None:
    """Path of a usable libLLVM (major >= 19), preferring 19; ``None`` if there is none."""
    for version in [19] + list(range(20, 31)):
        for pattern in _LLVM_PATTERNS:
            for path in sorted(glob.glob(pattern.format(v=version))):
                if os.path.isfile(path):
                    return path
    return None


def _cuda_usable() -> bool:
    """True when the CUDA driver loads and reports at least one device (no process abort possible)."""
    try:
        lib = ctypes.CDLL("libcuda.so.1")
        if lib.cuInit(0) != 0:
            return False
        count = ctypes.c_int(0)
        return lib.cuDeviceGetCount(ctypes.byref(count)) == 0 and count.value > 0
    except OSError:
        return False


def _configure_llvm() -> None:
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        major = _llvm_major(given)
        if not os.path.isfile(given):
            raise BackendError(f"DRJIT_LIBLLVM_PATH={given} does not exist")
        if major is not None and major < _MIN_LLVM_MAJOR:
            raise BackendError(
                f"DRJIT_LIBLLVM_PATH={given} is LLVM {major}; drjit 1.5.0 aborts inside LLVM < 19. "
                "Install LLVM 19 (Debian/Ubuntu: apt-get install libllvm19) and unset DRJIT_LIBLLVM_PATH")
        return
    path = find_libllvm()
    if path is None:
        raise BackendError(
            "No usable libLLVM found for Dr.Jit's CPU backend (need LLVM >= 19; LLVM 14-16 crash drjit "
            "1.5.0). Install it: 'apt-get install libllvm19' on Debian 12 / Ubuntu, or run "
            "scripts/bootstrap.sh; or set DRJIT_LIBLLVM_PATH to a libLLVM-19 shared library.")
    os.environ["DRJIT_LIBLLVM_PATH"] = path


def choose_variant() -> str:
    """The Mitsuba variant this process will use (see module docstring)."""
    forced = os.environ.get("WORKBENCH_VARIANT")
    if forced:
        if forced not in ("llvm_ad_mono", "cuda_ad_mono"):
            raise BackendError(f"WORKBENCH_VARIANT={forced!r}: use llvm_ad_mono or cuda_ad_mono")
        return forced
    return "cuda_ad_mono" if _cuda_usable() else "llvm_ad_mono"


def _start():
    variant = choose_variant()
    # Even on CUDA, Dr.Jit may touch the LLVM backend for host-side work: configure it when we can.
    try:
        _configure_llvm()
    except BackendError:
        if variant.startswith("llvm"):
            raise
    import drjit as _dr
    import mitsuba as _mi

    _mi.set_variant(variant)
    threads = os.environ.get("WORKBENCH_RENDER_THREADS", "")
    if threads.isdigit() and int(threads) > 0:
        _dr.set_thread_count(int(threads))
    return _mi, _dr, variant


mi, dr, VARIANT = _start()
