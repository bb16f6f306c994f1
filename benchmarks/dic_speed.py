"""DIC speed benchmark: points of interest per second per core, and peak memory.

A 2456 x 2058 Gaussian-speckle pair (autocorrelation speckle size ~4 px, 8-bit, sigma 1 grey noise) with a
smooth deformation (translation of a few pixels + 0.2 % strain + a small rotation); POIs every 8 px with a
50 px border (~72 000 points). Configurations (issue 'DIC engine'), biquintic interpolation:

- first order, subset 33 x 33;
- second order, subset 65 x 65 (the paper's subset);

each on 1 and 2 threads, timing
- IC-GN alone: every point starts from the displacement rounded to the pixel (what an FFT-CC initial guess
  gives), no propagation;
- the whole pipeline: prefilter + seed search + reliability-guided propagation (:func:`correlate`).

Reference figures given with the issue (same kind of 2-core machine): OpenCorr FFT-CC + IC-GN, bicubic,
g++ -O3 -march=native, OpenMP: first order 33 x 33: 16 700 POI/s per core (IC-GN), 14 300 (pipeline); second
order 65 x 65: 2 600 / 2 400; peak memory 667 MiB. OpenCorr (commit 500f447) built the same way and run on
this benchmark's own image pair on 2026-11-23, beside this engine, gave 5 400-6 400 / 4 400-5 100 (first
order) and 880-1 000 / 785-880 (second order) POI/s per core on that day's machine, with 660 MiB peak memory
(reports/dic_speed/README.md): the issue's figures come from a faster machine, so they are the stricter bar
and are the ones printed.

    .venv/bin/python benchmarks/dic_speed.py [--scale 1.0] [--threads 1,2] [--configs 1:33,2:65] [--repeats 3]
        [--peer-command "PROGRAM {ref} {tar} {order} {radius} {step} {border} {threads}"]

``--peer-command`` runs a peer DIC program on the same PNG pair, in the same process tree, right after each of
this engine's measurements (same configuration, same thread count, as many runs), so both see the machine in the
same state. The placeholders are filled in (``radius`` = (subset - 1) / 2, step 8 px, border 50 px); the program
must print one line ``pois N fftcc_s S prepare_s S icgn_s S mean_iterations K`` (its initial-guess stage, its
image preparation and its IC-GN, seconds). Printed: its POI/s per core for IC-GN alone and for the whole pipeline
(the three stages), and this engine's ratio to it. No peer is part of this project: reports/dic_speed/README.md
says how OpenCorr was built and driven for the figures there.

Shared virtual machines change speed from one second to the next (10-50 % seen here), so every measurement is
repeated and the best run and the median are printed; the best is the machine's speed when nothing else ran.

The images are made first and saved as 8-bit PNG files; the DIC then runs in a fresh process that reads them,
so the peak memory printed is that of the DIC alone (images included, speckle generation excluded).
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from measurement.dic import DICSettings, correlate
from scenes.sensor.noise import apply_sensor_noise
from scenes.image_pairs.analytic_fields import HomogeneousStrain
from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size

def _peak_mib() -> float:
    """High-water resident memory of this process, MiB (VmHWM: unlike ru_maxrss it is not inherited from the
    parent across fork/exec)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


OPENCORR = {(1, 33): (16_700, 14_300), (2, 65): (2_600, 2_400)}

# The arithmetic of IC-GN per subset pixel, counted from the kernels (measurement/dic/icgn.py, bspline.py) as
# operations on the FMA ports (a multiply, an add or a fused multiply-add is one), in float32 lanes: a float64
# operation fills half the lanes of a vector, so it counts 2.
#   one iteration, per pixel: warp (4 FMA + 2 subtractions) 6; the B-spline weights in x and y: quintic
#   2 x 29, cubic 2 x 13; the taps: quintic 36 + 6 row weights, cubic 16 + 4; the sums of the step and the
#   ZNCC in float64: 13 x 2 = 26 (the same for first and second order: the second order's extra monomials are
#   per row, not per pixel).
#   the reference subset, once per point, per pixel (float64): first order 36 x 2, second order 48 x 2 (the
#   Hessian's moments sum g_i g_j dx^a dy^b, a + b <= 2 or 4, row by row).
ITERATION_OPS = {"biquintic": 6 + 58 + 42 + 26, "bicubic": 6 + 26 + 20 + 26}
REFERENCE_OPS = {1: 72, 2: 96}


@numba.njit(fastmath=True)
def _fma_chains(acc, a, b, repeats):
    for _ in range(repeats):
        for j in range(acc.shape[0]):
            acc[j] = acc[j] * a + b
    return acc


def fma_peak_per_core(repeats: int = 3_000_000) -> float:
    """The machine's FMA limit, measured: float32 lane-FMAs per second on one core, many independent chains
    (what LLVM makes of the same vector code the DIC kernels get), best of three."""
    acc = np.ones(256, dtype=np.float32)
    _fma_chains(acc, np.float32(0.999), np.float32(0.001), 10)
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        _fma_chains(acc, np.float32(0.999), np.float32(0.001), repeats)
        best = min(best, time.perf_counter() - t)
    return acc.size * repeats / best


def fma_fraction(result, seconds: float, threads: int, interpolation: str, peak: float) -> tuple[float, float]:
    """Operations of one correlate run (every converged or failed point's reference subset and iterations) per
    second per core, and their share of ``peak``."""
    px = result.settings.subset_size ** 2
    prepared = np.count_nonzero(result.iterations > 0)
    ops = px * (prepared * REFERENCE_OPS[result.settings.order]
                + int(result.iterations.sum()) * ITERATION_OPS[interpolation])
    rate = ops / seconds / threads
    return rate, rate / peak


class _Field:
    """Translation + homogeneous strain + small rotation about the image centre (exact gradient for inversion)."""

    def __init__(self, centre):
        self.strain = HomogeneousStrain(0.002, -0.001, 0.0, centre_xy_px=centre)
        self.centre = centre
        self.angle = np.deg2rad(0.3)

    def __call__(self, x, y):
        su, sv = self.strain(x, y)
        dx, dy = x - self.centre[0], y - self.centre[1]
        c, s = np.cos(self.angle), np.sin(self.angle)
        return su + (c - 1) * dx - s * dy + 3.4, sv + s * dx + (c - 1) * dy - 2.7

    def gradient(self, x, y):
        g = self.strain.gradient(x, y)
        c, s = np.cos(self.angle), np.sin(self.angle)
        return g[0] + (c - 1), g[1] - s, g[2] + s, g[3] + (c - 1)


def make_pair(scale: float, seed: int = 0):
    shape = (int(round(2058 * scale)), int(round(2456 * scale)))
    pattern = gaussian_speckle(extent_for_shape(shape, margin_px=30), radius_for_speckle_size(4.0), seed=seed)
    field = _Field((shape[1] / 2, shape[0] / 2))
    reference = apply_sensor_noise(pattern.render_reference(shape), read_noise_grey=1.0, seed=seed + 1)
    deformed = apply_sensor_noise(pattern.render_deformed(shape, field), read_noise_grey=1.0, seed=seed + 2)
    return reference.astype(np.uint8), deformed.astype(np.uint8), field


PEER_KEYS = ("pois", "fftcc_s", "prepare_s", "icgn_s", "mean_iterations")


def run_peer(template: str, images: Path, order: int, subset: int, threads: int) -> dict:
    """Run the ``--peer-command`` once on the benchmark's pair; its printed figures (:data:`PEER_KEYS`)."""
    command = template.format(ref=images / "reference.png", tar=images / "deformed.png", order=order,
                              radius=(subset - 1) // 2, step=8, border=50, threads=threads)
    done = subprocess.run(command, shell=True, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"--peer-command failed (exit {done.returncode}): {command}\n{done.stderr.strip()}")
    for line in done.stdout.splitlines():
        words = line.split()
        figures = dict(zip(words[::2], words[1::2]))
        if all(k in figures for k in PEER_KEYS):
            return {k: float(figures[k]) for k in PEER_KEYS}
    raise SystemExit(f"--peer-command printed no line with {' '.join(PEER_KEYS)}: {command}\n{done.stdout[-500:]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=1.0, help="image scale (1 = 2456 x 2058)")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--configs", default="1:33,2:65", help="order:subset pairs")
    ap.add_argument("--repeats", type=int, default=3, help="runs per measurement (best and median printed)")
    ap.add_argument("--peer-command", default=None,
                    help="a peer DIC program run on the same pair after each measurement (see the module notes)")
    ap.add_argument("--images", type=Path, default=None, help=argparse.SUPPRESS)  # worker mode
    ap.add_argument("--compile-only", action="store_true", help=argparse.SUPPRESS)  # worker: fill the cache
    args = ap.parse_args()
    if args.images is None:
        import cv2
        t0 = time.perf_counter()
        reference, deformed, _ = make_pair(args.scale)
        rows, cols = reference.shape
        print(f"speckle pair {cols} x {rows} px made in {time.perf_counter() - t0:.1f} s")
        with tempfile.TemporaryDirectory() as tmp:
            cv2.imwrite(f"{tmp}/reference.png", reference)
            cv2.imwrite(f"{tmp}/deformed.png", deformed)
            # A fresh numba cache: numba does not notice a change in a function called from another module, so
            # a cache left by an older version of the code could be what gets timed. A first process compiles
            # into it; the measuring process then loads the kernels as an installed package would (compiling
            # in the measuring process would put LLVM's memory into its peak).
            env = {**os.environ, "NUMBA_CACHE_DIR": f"{tmp}/numba_cache"}
            worker = [sys.executable, __file__, "--scale", str(args.scale), "--threads", args.threads,
                      "--configs", args.configs, "--repeats", str(args.repeats), "--images", tmp]
            if args.peer_command:
                worker += ["--peer-command", args.peer_command]
            subprocess.run(worker + ["--compile-only"], check=True, env=env)
            subprocess.run(worker, check=True, env=env)
        return
    from measurement.image_io import read_grey
    reference = read_grey(args.images / "reference.png")
    deformed = read_grey(args.images / "deformed.png")
    rows, cols = reference.shape
    field = _Field((cols / 2, rows / 2))
    print(f"DIC process: images read, peak memory {_peak_mib():.0f} MiB")
    peak = fma_peak_per_core() if not args.compile_only else float("nan")
    if not args.compile_only:
        print(f"FMA limit, measured on one core: {peak / 1e9:.1f} G float32 lane-operations/s; per subset pixel: "
              f"one iteration {ITERATION_OPS['biquintic']} (biquintic) / {ITERATION_OPS['bicubic']} (bicubic) "
              f"operations, the reference subset {REFERENCE_OPS[1]} (first order) / {REFERENCE_OPS[2]} (second)")
    roi = (50, 50, cols - 50, rows - 50)
    for config in args.configs.split(","):
        order, subset = (int(v) for v in config.split(":"))
        settings = DICSettings(subset_size=subset, step=8, order=order, interpolation="biquintic")
        guess = lambda x, y: tuple(np.round(c) for c in field(x, y))  # noqa: E731
        # warm-up (numba compilation / cache load) on a small crop, on every thread count
        for threads in (int(t) for t in args.threads.split(",")):
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            correlate(reference[:400, :400], deformed[:400, :400], settings)
            correlate(reference[:400, :400], deformed[:400, :400], settings, initial_parameters=guess)
        if args.compile_only:
            continue
        for threads in (int(t) for t in args.threads.split(",")):
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            icgn_s, pipeline_s = [], []
            for _ in range(max(1, args.repeats)):
                result = correlate(reference, deformed, settings, roi=roi, initial_parameters=guess)
                icgn_s.append(result.timings_s["icgn"])
                t = time.perf_counter()
                full = correlate(reference, deformed, settings, roi=roi)
                pipeline_s.append(time.perf_counter() - t)
            n = result.x.size
            ok = result.converged
            u_true, v_true = field(result.x[ok].astype(float), result.y[ok].astype(float))
            error = np.hypot(result.u[ok] - u_true, result.v[ok] - v_true)
            print(f"order {order}, subset {subset}, {threads} thread(s), {n} POI, {len(icgn_s)} runs:")
            print(f"    IC-GN alone     best {n / min(icgn_s) / threads:>8,.0f}  median "
                  f"{n / np.median(icgn_s) / threads:>8,.0f} POI/s per core ({min(icgn_s):.2f} s; converged "
                  f"{ok.mean():.4f}, mean iterations {result.iterations[ok].mean():.2f}, RMS error "
                  f"{np.sqrt(np.mean(error ** 2)):.4f} px)")
            rate, share = fma_fraction(result, min(icgn_s), threads, settings.interpolation, peak)
            limit_poi = n / min(icgn_s) / threads / share
            print(f"    IC-GN alone at {rate / 1e9:.2f} G operations/s per core = {100 * share:.1f} % of the FMA "
                  f"limit (at the limit: {limit_poi:,.0f} POI/s per core)")
            ok = full.converged
            print(f"    whole pipeline  best {n / min(pipeline_s) / threads:>8,.0f}  median "
                  f"{n / np.median(pipeline_s) / threads:>8,.0f} POI/s per core ({min(pipeline_s):.2f} s; last run's "
                  f"stages {', '.join(f'{k} {v:.2f} s' for k, v in full.timings_s.items())}; converged "
                  f"{ok.mean():.4f}, mean iterations {full.iterations[ok].mean():.2f})")
            if args.peer_command:
                peer = [run_peer(args.peer_command, args.images, order, subset, threads)
                        for _ in range(max(1, args.repeats))]
                peer_icgn = min(p["icgn_s"] for p in peer)
                peer_pipe = min(p["fftcc_s"] + p["prepare_s"] + p["icgn_s"] for p in peer)
                m = peer[0]["pois"]
                print(f"    peer, same pair and threads, {len(peer)} runs ({m} POI, mean iterations "
                      f"{peer[0]['mean_iterations']:.2f}): IC-GN alone {m / peer_icgn / threads:>8,.0f}, whole "
                      f"pipeline {m / peer_pipe / threads:>8,.0f} POI/s per core (best); this engine's ratio: "
                      f"IC-GN {(n / min(icgn_s)) / (m / peer_icgn):.1f}x, pipeline "
                      f"{(n / min(pipeline_s)) / (m / peer_pipe):.1f}x")
        ref_icgn, ref_pipe = OPENCORR.get((order, subset), (None, None))
        if ref_icgn:
            print(f"    OpenCorr reference (bicubic): {ref_icgn:,} POI/s per core IC-GN, {ref_pipe:,} pipeline")
    if args.compile_only:
        print(f"numba kernels compiled into {os.environ.get('NUMBA_CACHE_DIR', 'the default cache')}")
        return
    peak_mib = _peak_mib()
    print(f"peak memory of the DIC process (images, splines, numba runtime): {peak_mib:.0f} MiB; "
          f"OpenCorr reference 667 MiB")


if __name__ == "__main__":
    main()
