"""The times the README and the install page promise a new user, measured as a new user meets them.

    .venv/bin/python benchmarks/new_user_times.py [--only paper_quick,twin_gt4,tests] [--out reports/new_user_times]

Each command runs in a subprocess as from a fresh clone after ``scripts/bootstrap.sh``: an empty HOME (so an empty
render store), an empty numba cache (``NUMBA_CACHE_DIR``: a fresh clone has no compiled kernels), outputs in a
temporary folder. Set-up itself (``bootstrap.sh``: apt and pip) is not counted.

* ``paper_quick``: the README's main job, ``workbench reproduce paper --quick``;
* ``twin_gt4``: the README's twin example on the Stereo-DIC Challenge's GT4 rig (needs ``data/twin``:
  ``scripts/fetch_twin_data.sh``; left out, said, without it);
* ``tests``: the README's test command, ``python -m pytest`` (the default suite; ``tests/test_docs_times.py``, a
  check of this record taking well under a second, is left out of the timed run).

Writes ``times.json`` (seconds, the machine, the date, the commit) and ``README.md``; a measurement kept from an
earlier run is carried over when ``--only`` leaves it out. The docs quote these figures in the words of
:func:`phrase`, and ``tests/test_docs_times.py`` checks that they do. Run it on a quiet machine.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TWIN_DATA = ROOT / "data" / "twin" / "gt4"

#: What each measured command is, for the record.
WHAT = {"paper_quick": "workbench reproduce paper --quick (the README's main job)",
        "twin_gt4": "workbench twin on the GT4 rig (the README's twin example)",
        "tests": "python -m pytest (the README's test command, the default suite)"}


def duration_text(seconds: float) -> str:
    """``"68 s"`` under two minutes, ``"2.6 min"`` under ten, ``"18 min"`` above."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    minutes = seconds / 60.0
    return f"{minutes:.1f} min" if minutes < 10 else f"{minutes:.0f} min"


def machine_text(machine: dict) -> str:
    """``"2 cores, 23 GiB (Intel(R) Xeon(R) Processor), 2026-12-04"``."""
    return f"{machine['cores']} cores, {machine['memory_gib']:.0f} GiB ({machine['cpu']}), {machine['date']}"


def phrase(times: dict, key: str) -> str:
    """How the docs state a measured time: ``"18 min measured on 2 cores, 23 GiB (...), 2026-12-04"``."""
    entry = times["runs"][key]
    return f"{duration_text(entry['seconds'])} measured on {machine_text(entry['machine'])}"


def _machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
    return {"cores": os.cpu_count(), "memory_gib": round(memory, 1), "cpu": cpu,
            "date": datetime.date.today().isoformat(), "python": platform.python_version()}


def _commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None


def _command(key: str, work: Path) -> list[str]:
    py = sys.executable
    if key == "paper_quick":
        return [py, "-m", "workbench.cli", "reproduce", "paper", "--quick", "--out", str(work / "paper_quick")]
    if key == "twin_gt4":
        g = TWIN_DATA
        return [py, "-m", "workbench.cli", "twin", "--calib", str(g / "cal.xml"), "--left", str(g / "GT4-0000_0.tif"),
                "--right", str(g / "GT4-0000_1.tif"), "--static-left", str(g / "GT4-0001_0.tif"),
                "--static-right", str(g / "GT4-0001_1.tif"), "--auto-roi", "--subset", "25", "--step", "12",
                "--out", str(work / "twin_gt4")]
    if key == "tests":
        # the docs' check of this very record is left out (it would fail until the docs quote the new figure)
        return [py, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--deselect", "tests/test_docs_times.py"]
    raise ValueError(f"--only: unknown run {key!r}; choose from {', '.join(WHAT)}")


def measure(key: str) -> dict:
    """Run one command as a new user would (module notes); its wall time and exit status."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "home").mkdir()
        env = {k: v for k, v in os.environ.items() if k not in ("WORKBENCH_STORE", "XDG_CACHE_HOME")}
        env.update(HOME=str(tmp / "home"), NUMBA_CACHE_DIR=str(tmp / "numba"))
        command = _command(key, tmp)
        print(f"[{key}] {' '.join(command[2:])}", flush=True)
        start = time.perf_counter()
        proc = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
        seconds = time.perf_counter() - start
    tail = (proc.stdout.strip() or proc.stderr.strip()).splitlines()[-1:] or [""]
    print(f"[{key}] {duration_text(seconds)} ({seconds:.1f} s), exit {proc.returncode}: {tail[0]}", flush=True)
    return {"what": WHAT[key], "seconds": round(seconds, 1), "returncode": proc.returncode, "last_line": tail[0],
            "machine": _machine(), "commit": _commit()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", default=",".join(WHAT), help=f"comma-separated runs among {', '.join(WHAT)}")
    p.add_argument("--out", type=Path, default=ROOT / "reports" / "new_user_times")
    args = p.parse_args()
    keys = [k.strip() for k in args.only.split(",") if k.strip()]
    for key in keys:
        _command(key, Path("."))                              # refuse an unknown name before any run
    path = args.out / "times.json"
    doc = json.loads(path.read_text()) if path.is_file() else {"runs": {}}
    for key in keys:
        if key == "twin_gt4" and not TWIN_DATA.is_dir():
            print(f"[twin_gt4] left out: no {TWIN_DATA} (bash scripts/fetch_twin_data.sh)")
            continue
        doc["runs"][key] = measure(key)
    doc["about"] = ("Wall times of the commands the README and docs/install.rst quote, each run as from a fresh clone "
                    "after bootstrap.sh (empty HOME and render store, empty numba cache); benchmarks/new_user_times.py")
    args.out.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT))
    from labio.atomic import atomic_write_text

    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    lines = ["# Times a new user meets", "", doc["about"] + ".", "", "| command | wall time | exit | machine | commit |",
             "|---|---|---|---|---|"]
    for key, entry in doc["runs"].items():
        lines.append(f"| {entry['what']} | {duration_text(entry['seconds'])} ({entry['seconds']} s) | "
                     f"{entry['returncode']} | {machine_text(entry['machine'])} | {(entry['commit'] or '-')[:10]} |")
    atomic_write_text(args.out / "README.md", "\n".join(lines) + "\n")
    print(f"wrote {path}")
    return 0 if all(doc["runs"][k]["returncode"] == 0 for k in keys if k in doc["runs"]) else 1


if __name__ == "__main__":
    sys.exit(main())
