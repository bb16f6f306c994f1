"""labio.memory: freed image-sized blocks are reused, not faulted in again page by page (the kernel's own count of
minor page faults is the reference), in the process and in the processes it starts."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# 40 image-sized (40 MB) arrays made and freed; prints the minor page faults they cost.
LOOP = """
import resource, numpy as np
a = np.ones(5_000_000); del a
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    a = np.ones(5_000_000); b = a * 2.0; del a, b
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _faults(code: str, **env) -> int:
    from labio.memory import ENVIRONMENT

    # this test process may carry the setting already (any test that ran the CLI in-process): start from none
    base = {k: v for k, v in os.environ.items() if k not in ENVIRONMENT}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT,
                          env={**base, "PYTHONPATH": str(ROOT), **env})
    return int(done.stdout.split()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_freed_images_are_reused_at_a_tenth_of_the_page_faults():
    default = _faults(LOOP, WORKBENCH_KEEP_FREED_MEMORY="0")
    kept = _faults("from labio.memory import keep_freed_memory\nassert keep_freed_memory()\n" + LOOP)
    assert default > 2000, default            # 40 x 40 MB fresh mappings: the kernel faults each of them in
    assert kept * 10 < default, (kept, default)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_a_child_started_after_it_reads_the_setting_from_its_environment():
    from labio.memory import ENVIRONMENT

    default = _faults(LOOP, WORKBENCH_KEEP_FREED_MEMORY="0")
    child = _faults(LOOP, **ENVIRONMENT)      # no call in the child: glibc reads MALLOC_*_ at start-up
    assert child * 10 < default, (child, default)


def test_the_switch_leaves_malloc_alone(monkeypatch):
    from labio import memory

    monkeypatch.setenv(memory.SWITCH, "0")
    for key in memory.ENVIRONMENT:
        monkeypatch.delenv(key, raising=False)
    assert memory.keep_freed_memory() is False
    assert not any(key in os.environ for key in memory.ENVIRONMENT)
