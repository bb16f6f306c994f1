"""SHA-256 of every image and truth file the truth side writes, for a before/after check of a refactoring.

Runs, each from an empty render store in a scratch folder: the paper's quick run (every experiment's rendered
images and truth, as the store keeps them), the four catalog specimens at test scale (``workbench catalog --scale``
then ``workbench render specimen``), and the twin's rendered rig (a flat plate rendered through the paper rig at
quarter scale, then ``workbench twin`` on it: the numbers of its twin.json). Prints one ``sha256  path`` line per file, sorted,
and writes them to ``--out``; compare two such files with ``diff`` (give both runs the same ``--work`` folder:
the truth files name the paths of their inputs). Timing and provenance files (which hold dates,
durations, versions) are left out, and JSON files are hashed without their timing keys: they are not images or
truth.

Usage::

    .venv/bin/python benchmarks/truth_hashes.py --out hashes_before.txt [--work DIR] [--only paper,catalog,twin]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

#: Files whose bytes hold times, dates, versions or paths, not images or truth.
SKIPPED_SUFFIXES = (".html", ".md", ".log", ".svg", ".txt", ".xml")
SKIPPED_NAMES = ("provenance.json", "manifest.json", "summary.json", "timings.json", "progress.json", "export.json")
CATALOG = ("beam", "notched_coupon", "plate_with_hole", "pressurised_cylinder")
TWIN_SCENARIO = ('experiment = "specimen"\nseed = 3\n[rig]\nname = "paper"\nscale = 0.25\n'
                 '[render]\nread_noise_grey = 2.0\nelectrons_per_grey = 20.0\n'
                 '[specimen]\nmesh = "plate.e"\nstatic_offset_px = [0.0, 0.0]\n')


def workbench(*args: str, store: Path) -> None:
    """Run the ``workbench`` CLI of this environment with its own render store; fail loudly."""
    exe = Path(sys.executable).with_name("workbench")
    env = dict(os.environ, WORKBENCH_STORE=str(store))
    subprocess.run([str(exe), *args], check=True, env=env, stdout=subprocess.DEVNULL)


#: JSON keys that hold seconds (they differ from run to run; the rest of the file is truth).
TIMING_KEYS = ("timings_s", "seconds", "render_s", "solve_time_s", "elapsed_s", "wall_s")


def digest(path: Path) -> str:
    """SHA-256 of the file's bytes; of a JSON file, of its content without timing keys (canonical form)."""
    if path.suffix == ".json":
        doc = without_timings(json.loads(path.read_text()))
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def hashed_files(root: Path, label: str) -> list[str]:
    """``sha256  label/relative path`` of every image/truth file under ``root``."""
    lines = []
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        if path.suffix in SKIPPED_SUFFIXES or path.name in SKIPPED_NAMES or path.name.startswith("."):
            continue
        lines.append(f"{digest(path)}  {label}/{path.relative_to(root)}")
    return lines


def without_timings(value):
    """A JSON value with every timing entry (:data:`TIMING_KEYS`) dropped, at any depth."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def paper(work: Path) -> list[str]:
    store = work / "paper_store"
    workbench("reproduce", "paper", "--quick", "--out", str(work / "paper"), store=store)
    return hashed_files(store, "paper_store")


def catalog(work: Path) -> list[str]:
    lines = []
    for name in CATALOG:
        folder = work / f"catalog_{name}"
        workbench("catalog", name, "--scale", "0.25", "--out", str(folder / "scenario"), store=work / "catalog_store")
        workbench("render", "specimen", str(folder / "scenario" / "scenario.toml"), "--out", str(folder / "data"),
                  store=work / "catalog_store")
        lines += hashed_files(folder / "data", f"catalog_{name}/data")
    return lines


def twin(work: Path) -> list[str]:
    import numpy as np
    import skfem
    from skfem.io.meshio import to_meshio

    import importlib

    try:
        write_exodus = importlib.import_module("scenes.specimens.fe_files").write_exodus
    except ImportError:  # before the move into rooms (issue 41)
        write_exodus = importlib.import_module("scenes.fe_files").write_exodus

    folder = work / "twin"
    folder.mkdir()
    m = to_meshio(skfem.MeshTet.init_tensor(np.linspace(-30, 30, 7), np.linspace(-20, 20, 5), np.linspace(0, 3, 2)))
    write_exodus(folder / "plate.e", m.points, {"tetra": m.cells[0].data}, np.zeros((1, *m.points.shape)),
                 times=[0.0])
    (folder / "plate.toml").write_text(TWIN_SCENARIO)
    store = work / "twin_store"
    workbench("render", "specimen", str(folder / "plate.toml"), "--out", str(folder / "data"), store=store)
    workbench("export", str(folder / "data"), "--format", "native", "--out", str(folder / "ex"), store=store)
    lines = hashed_files(folder / "data", "twin/data")
    ex = folder / "ex"
    workbench("twin", "--calib", str(ex / "calibration.json"), "--left", str(ex / "left_00.png"),
              "--right", str(ex / "right_00.png"), "--static-left", str(ex / "left_01.png"),
              "--static-right", str(ex / "right_01.png"), "--auto-roi", "--subset", "21", "--step", "6",
              "--no-whatif", "--seed", "1", "--out", str(folder / "twin_out"), store=store)
    lines += hashed_files(ex, "twin/ex")
    summary = json.loads((folder / "twin_out" / "twin.json").read_text())
    summary = without_timings(summary)
    lines.append(f"{hashlib.sha256(json.dumps(summary, sort_keys=True).encode()).hexdigest()}  twin/summary-numbers")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="file for the sorted hash lines")
    parser.add_argument("--work", help="scratch folder (default: a new temporary one)")
    parser.add_argument("--only", default="paper,catalog,twin", help="comma-separated: paper, catalog, twin")
    args = parser.parse_args(argv)
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="truth_hashes_"))
    work.mkdir(parents=True, exist_ok=True)
    lines = []
    for part in args.only.split(","):
        lines += {"paper": paper, "catalog": catalog, "twin": twin}[part](work)
        print(f"{part}: {len(lines)} files hashed so far", file=sys.stderr)
    Path(args.out).write_text("\n".join(sorted(lines)) + "\n")
    print(f"{len(lines)} files -> {args.out} (work folder {work})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
