"""Memory of a long stereo sequence (issue 39: a 1 000-state sequence at 5 MP within 4 GiB peak).

A speckled plate is rendered through the paper rig (``--scale 1``: 2456 x 2058 px, as
``benchmarks/uncertainty_cost.py`` renders it) in a reference and a translated state; the sequence's states are that
translated pair with a fresh noise draw of 1 grey added to it, so every state is a new measurement of the same
motion. The instrument measures them one after the other as ``workbench stereo`` does (paper settings,
with the per-point uncertainty, each state warm-started from the one before, nothing kept but the current state and
its per-point CSV written to a scratch folder), with malloc set as the ``workbench`` command sets it
(:mod:`labio.memory`). Printed: the process's resident memory after the reference shape and
after states 1, 10, 100 ..., its high-water mark, and the growth per state over the second half of the run (0 when
the sequence streams).

    .venv/bin/python benchmarks/sequence_memory.py [--states 1000] [--scale 1.0] [--roi-fraction 0.4]

Run it alone: the machine's 2 cores are the benchmark's.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def _status_mib(key: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return float(line.split()[1]) / 1024
    return float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=1000)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--roi-fraction", type=float, default=0.4,
                    help="side of the central ROI as a fraction of the image's (0.4: ~32 500 points at scale 1; a "
                         "smaller one makes a long run affordable, the images stay 5 MP)")
    args = ap.parse_args(argv)
    if not 0.05 <= args.roi_fraction <= 0.9:
        raise SystemExit("--roi-fraction must lie in [0.05, 0.9]")
    if args.states < 2:
        raise SystemExit("--states must be at least 2")

    from labio.memory import keep_freed_memory
    from uncertainty_cost import scene

    print(f"glibc keeps freed blocks (as the workbench CLI does): {keep_freed_memory()}")

    from measurement.stereo_dic import STEREO_DIC_SETTINGS, measure_state, reference_shape
    from measurement.stereo_io import write_state_csv

    rig, im, cams, _ = scene(args.scale)
    w, h, f = rig.left.width, rig.left.height, args.roi_fraction
    roi = (int((0.5 - f / 2) * w), int((0.5 - f / 2) * h), int((0.5 + f / 2) * w), int((0.5 + f / 2) * h))
    shape = reference_shape(*cams, im["left_ref"], im["right_ref"], STEREO_DIC_SETTINGS, roi=roi)
    base = {"after reference shape": _status_mib("VmRSS")}
    print(f"{shape.x.size} points; resident after the reference shape {base['after reference shape']:.0f} MiB")
    marks = {1, 10, 100, 1000, 10000, args.states}
    rss, previous = [], None
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as scratch:
        for k in range(1, args.states + 1):
            rng = np.random.default_rng(k)       # a fresh draw per state, seeded
            left = np.clip(im["left_def"] + rng.normal(0.0, 1.0, im["left_def"].shape), 0, 255)
            right = np.clip(im["right_def"] + rng.normal(0.0, 1.0, im["right_def"].shape), 0, 255)
            state = measure_state(*cams, shape, im["left_ref"], left, right, STEREO_DIC_SETTINGS, previous=previous,
                                  name=f"state {k}")
            write_state_csv(Path(scratch) / "state.csv", shape, state)
            previous = state
            rss.append(_status_mib("VmRSS"))
            if k in marks:
                print(f"state {k}: resident {rss[-1]:.0f} MiB, high-water {_status_mib('VmHWM'):.0f} MiB, "
                      f"{(time.perf_counter() - start) / k:.2f} s per state, seeds {state.seeded_by}", flush=True)
    half = np.asarray(rss[len(rss) // 2:])
    slope = np.polyfit(np.arange(half.size), half, 1)[0] if half.size > 2 else float("nan")
    print(f"{args.states} states: peak resident memory {_status_mib('VmHWM'):.0f} MiB (goal 4096 MiB); growth over the "
          f"second half {1024 * slope:.1f} KiB per state")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
