"""numba's cache of the measurement.dic kernels is keyed on the sources of the whole package
(measurement/dic/_numba_cache.py), so an edited callee in another module never leaves a stale kernel.

Each check runs in fresh processes on a temporary copy of ``measurement/`` (its own ``__pycache__``, no
``NUMBA_CACHE_DIR``), with a probe kernel added to the copied package: ``_probe.probe`` (cached) calls
``_probe_callee.value`` (another module, not cached itself, so compiled into the probe's machine code). numba
alone stamps ``probe`` with ``_probe.py`` only and, after ``value`` is edited, loads the stale kernel (checked
by hand against a copy without the guard: it returned the old value).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PROBE = """
import numba

from . import _probe_callee


@numba.njit(cache=True)
def probe(x):
    return _probe_callee.value(x)
"""

CALLEE = """
import numba


@numba.njit
def value(x):
    return x + {offset}
"""

RUN = """
import json, sys, warnings
warnings.simplefilter("always")
import measurement
assert measurement.__file__.startswith(sys.argv[1]), measurement.__file__
from measurement.dic import _probe
result = _probe.probe(1)
locator = _probe.probe._cache._impl._locator
print(json.dumps({"value": int(result), "hits": sum(_probe.probe.stats.cache_hits.values()),
                  "misses": sum(_probe.probe.stats.cache_misses.values()), "locator": type(locator).__name__,
                  "path": locator.get_cache_path()}))
"""


@pytest.fixture
def package_copy(tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(ROOT / "measurement", root / "measurement", ignore=shutil.ignore_patterns("__pycache__"))
    (root / "measurement" / "dic" / "_probe.py").write_text(PROBE)
    (root / "measurement" / "dic" / "_probe_callee.py").write_text(CALLEE.format(offset=1))
    return root


def _run(root: Path, **env_changes) -> tuple[dict, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    env.update(env_changes)
    done = subprocess.run([sys.executable, "-c", RUN, str(root)], cwd=root, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


def test_an_edited_callee_in_another_module_recompiles_the_cached_kernel(package_copy):
    first, _ = _run(package_copy)
    assert (first["value"], first["hits"], first["misses"]) == (2, 0, 1)
    assert first["locator"] == "PackageInTreeLocator"
    assert Path(first["path"]) == package_copy / "measurement" / "dic" / "__pycache__"
    # The cache is used: a second process loads the kernel instead of compiling it.
    second, _ = _run(package_copy)
    assert (second["value"], second["hits"], second["misses"]) == (2, 1, 0)
    # Edit only the callee (its own module, not the cached kernel's file): the new code runs.
    (package_copy / "measurement" / "dic" / "_probe_callee.py").write_text(CALLEE.format(offset=10))
    edited, _ = _run(package_copy)
    assert (edited["value"], edited["hits"], edited["misses"]) == (11, 0, 1)
    again, _ = _run(package_copy)
    assert (again["value"], again["hits"], again["misses"]) == (11, 1, 0)


def test_no_writable_cache_folder_means_a_warning_and_no_cache_not_a_crash(package_copy, tmp_path):
    # Root can write anywhere, so make the folders impossible instead: a file where __pycache__ and the
    # user cache directory would be.
    (package_copy / "measurement" / "dic" / "__pycache__").write_text("not a folder")
    blocker = tmp_path / "blocker"
    blocker.write_text("not a folder")
    env = {"XDG_CACHE_HOME": str(blocker / "cache"), "HOME": str(blocker / "home")}
    result, stderr = _run(package_copy, **env)
    assert result["value"] == 2
    assert result["locator"] == "PackageTemporaryLocator"
    assert "numba cannot write a cache for measurement.dic" in stderr
    assert "compile in every process" in stderr


def test_numba_cache_dir_is_honoured_and_keyed_the_same_way(package_copy, tmp_path):
    cache = tmp_path / "numba-cache"
    first, _ = _run(package_copy, NUMBA_CACHE_DIR=str(cache))
    assert first["locator"] == "PackageUserProvidedLocator"
    assert Path(first["path"]).is_relative_to(cache)
    (package_copy / "measurement" / "dic" / "_probe_callee.py").write_text(CALLEE.format(offset=5))
    edited, _ = _run(package_copy, NUMBA_CACHE_DIR=str(cache))
    assert (edited["value"], edited["misses"]) == (6, 1)


def test_the_real_kernels_use_the_package_stamp_and_the_stamp_follows_every_source(tmp_path):
    from measurement.dic import _numba_cache, guide, icgn

    for kernel in (icgn.solve_point, icgn.correlate_batch, guide._propagate_region):
        locator = kernel._cache._impl._locator
        assert isinstance(locator, _numba_cache.LOCATORS), type(locator)
        assert _numba_cache.SOURCE_HASH in locator.get_source_stamp()
    copy = tmp_path / "dic"
    shutil.copytree(_numba_cache.PACKAGE_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert _numba_cache.package_source_hash(copy) == _numba_cache.SOURCE_HASH
    source = (copy / "shape_functions.py").read_text()
    (copy / "shape_functions.py").write_text(source + "\n# an edit\n")
    assert _numba_cache.package_source_hash(copy) != _numba_cache.SOURCE_HASH
