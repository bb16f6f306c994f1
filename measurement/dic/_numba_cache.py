"""numba's on-disk cache of the ``measurement.dic`` kernels, keyed on the sources of the whole package.

numba stamps a cached kernel with the source of the file that defines it, and nothing else. A kernel that
calls functions of *other* modules (``icgn.iterate`` inlines ``shape_functions.compose_inverse`` and the
B-spline weights of ``bspline``; ``guide`` calls ``icgn``) is loaded unchanged after one of those callees is
edited: stale machine code, silently. This module gives numba, for the functions defined in this package only,
cache locators whose source stamp is the SHA-256 of every ``*.py`` file of the package: after any edit
anywhere in ``measurement/dic`` each cached kernel of the package no longer matches its index, so numba
compiles it again on first use and overwrites the stale entry.

Where the cache lives is numba's usual choice: ``NUMBA_CACHE_DIR`` when set, else ``__pycache__`` beside
the sources, else numba's user-wide cache directory. When none of them can be written (a read-only install
with no writable home), kernels are cached in a temporary directory for this process only, removed at exit,
and a warning says that every process compiles again (numba itself would refuse to import the package).

The guard must be installed before the kernels are defined: ``measurement/dic/__init__.py`` imports this
module first. Hashing the package's sources (~120 kB) at import takes well under a millisecond.
"""
from __future__ import annotations

import atexit
import hashlib
import shutil
import tempfile
import warnings
from pathlib import Path

from numba.core import caching, config

#: The package whose kernels the guard covers.
PACKAGE_DIR = Path(__file__).resolve().parent


def package_source_hash(directory: Path = PACKAGE_DIR) -> str:
    """SHA-256 over the names and contents of every ``*.py`` file under ``directory``, in sorted order."""
    digest = hashlib.sha256()
    for path in sorted(directory.rglob("*.py")):
        digest.update(path.relative_to(directory).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")
    return digest.hexdigest()


#: Stamp of the sources this process imported.
SOURCE_HASH = package_source_hash()


def _in_package(py_file: str) -> bool:
    try:
        return Path(py_file).resolve().is_relative_to(PACKAGE_DIR)
    except (OSError, ValueError):
        return False


class _PackageStamp:
    """Mixin: applies to functions of this package only, stamped with the package's source hash."""

    def get_source_stamp(self):
        return f"measurement.dic sources sha256 {SOURCE_HASH}"

    @classmethod
    def from_function(cls, py_func, py_file):
        if not _in_package(py_file):
            return None
        return super().from_function(py_func, py_file)


class PackageUserProvidedLocator(_PackageStamp, caching.UserProvidedCacheLocator):
    """``NUMBA_CACHE_DIR``, when set."""


class PackageInTreeLocator(_PackageStamp, caching.InTreeCacheLocator):
    """``__pycache__`` beside the sources, when writable."""


class PackageUserWideLocator(_PackageStamp, caching.UserWideCacheLocator):
    """numba's user-wide cache directory, when writable."""


_temporary = {}


def _temporary_cache_dir() -> str:
    if "path" not in _temporary:
        path = tempfile.mkdtemp(prefix="measurement-dic-numba-")
        atexit.register(shutil.rmtree, path, ignore_errors=True)
        _temporary["path"] = path
        warnings.warn("numba cannot write a cache for measurement.dic (NUMBA_CACHE_DIR unset or read-only, "
                      f"{PACKAGE_DIR / '__pycache__'} and the user cache directory not writable): its kernels "
                      "compile in every process (set NUMBA_CACHE_DIR to a writable folder to keep them)",
                      RuntimeWarning, stacklevel=2)
    return _temporary["path"]


class PackageTemporaryLocator(_PackageStamp, caching.InTreeCacheLocator):
    """Last resort: a temporary directory for this process (no caching across processes), with a warning."""

    def __init__(self, py_func, py_file):
        super().__init__(py_func, py_file)
        self._cache_path = _temporary_cache_dir()


LOCATORS = (PackageUserProvidedLocator, PackageInTreeLocator, PackageUserWideLocator, PackageTemporaryLocator)


def install() -> bool:
    """Put the package's locators first in numba's list (once); False, with a warning, if that cannot be done."""
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    locators = getattr(impl, "_locator_classes", None)
    if not isinstance(locators, list):
        warnings.warn("this numba version's cache has no locator list: measurement.dic cannot key its cache on "
                      "the package sources; clear measurement/dic/__pycache__ after editing the package",
                      RuntimeWarning, stacklevel=2)
        return False
    if getattr(config, "CACHE_LOCATOR_CLASSES", ""):
        warnings.warn("NUMBA_CACHE_LOCATOR_CLASSES is set, so numba uses those locators and measurement.dic "
                      "cannot key its cache on the package sources; clear the cache after editing the package",
                      RuntimeWarning, stacklevel=2)
        return False
    if not any(cls in locators for cls in LOCATORS):
        locators[0:0] = LOCATORS
    return True


INSTALLED = install()
