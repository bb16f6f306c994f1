"""Sweep throughput on a LocalCluster: 1 process worker vs 2, the same study, in one script.

Goal (error-budget issue): throughput from 1 to 2 workers on 2 cores >= 1.8x. The study is a 2-D DIC grid
(noise x subset x seeds, 512 px images): every case renders its pair into a fresh store and measures it, so
both runs do identical work. Each cluster is started and warmed first (one case per worker: imports, numba
kernels from the on-disk cache); the timed part is the sweep itself. Nothing else may run on the machine.

    .venv/bin/python benchmarks/sweep_throughput.py [--cases-per-axis 6] [--repeats 2]
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from workbench.store import DatasetStore
from workbench.studies.study import parse_study
from workbench.studies.sweep import run_sweep, start_client


def study(noise: list[float], subsets: list[int], repeats: int, seed0: int = 0):
    return parse_study({"study": {"name": "throughput", "seeds": list(range(seed0, seed0 + repeats))},
                        "scenario": {"experiment": "dic2d", "render": {"bit_depth": 0}, "image2d": {"size_px": 512}},
                        "instrument": {"step_px": 5, "shape_order": 2},
                        "axis": [{"name": "noise", "parameter": "scenario.render.read_noise_grey", "values": noise},
                                 {"name": "subset", "parameter": "instrument.subset_px", "values": subsets}]},
                       "throughput")


def timed(workers: int, n: int, repeats: int, root: Path) -> tuple[float, int]:
    client, cluster = start_client(None, workers)
    try:
        # warm-up: one case per worker (imports, numba kernels) on seeds the timed study does not use
        run_sweep(study([1.0], [21] * 1, workers, seed0=1000), root / f"warm{workers}",
                  store=DatasetStore(root / f"warm-store{workers}"), client=client, progress=False)
        s = study([0.5 + 0.5 * i for i in range(n)], [21 + 10 * i for i in range(n)], repeats)
        start = time.perf_counter()
        summary = run_sweep(s, root / f"run{workers}", store=DatasetStore(root / f"store{workers}"), client=client,
                            progress=False)
        seconds = time.perf_counter() - start
        assert summary.failed == 0 and summary.computed == summary.total
        return seconds, summary.total
    finally:
        client.close()
        cluster.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases-per-axis", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="sweep-throughput-"))
    try:
        results = {w: timed(w, args.cases_per_axis, args.repeats, root) for w in (1, 2)}
    finally:
        shutil.rmtree(root, ignore_errors=True)
    for w, (seconds, cases) in results.items():
        print(f"{w} worker(s): {cases} cases in {seconds:.1f} s = {cases / seconds:.3f} cases/s")
    speedup = results[1][0] / results[2][0]
    print(f"throughput 2 workers / 1 worker: {speedup:.2f}x (goal >= 1.8x)")


if __name__ == "__main__":
    main()
