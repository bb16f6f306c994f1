"""Wall time of the accuracy gate (gates/gates.toml) on this machine: cold (empty render store) and warm.

    .venv/bin/python benchmarks/gate_speed.py [--out reports/gate_speed]

Runs ``workbench gate`` twice in subprocesses with one fresh store, prints the two wall times and each check's
time, and writes ``gate_speed.json`` / ``gate_speed.md``. The issue's goal: the quick suite in <= 5 min on 2
cores. Run it on a quiet machine.
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "reports" / "gate_speed")
    args = p.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "WORKBENCH_STORE": str(Path(tmp) / "store")}
        for label in ("cold (empty store: renders included)", "warm (renders in the store)"):
            out = Path(tmp) / label.split()[0]
            start = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "workbench.cli", "gate", str(ROOT / "gates" / "gates.toml"),
                                   "--out", str(out)], env=env, capture_output=True, text=True)
            wall = time.perf_counter() - start
            record = json.loads((out / "gate.json").read_text())
            rows.append({"run": label, "wall_s": round(wall, 1), "passed": record["passed"],
                         "checks_s": record["timings_s"], "returncode": proc.returncode})
            print(f"{label}: {wall:.1f} s wall, gate {'passed' if record['passed'] else 'FAILED'}; "
                  + ", ".join(f"{k} {v:.1f} s" for k, v in record["timings_s"].items()))
    doc = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "runs": rows,
           "goal": "quick suite <= 300 s on 2 cores"}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "gate_speed.json").write_text(json.dumps(doc, indent=1))
    lines = ["# Accuracy gate wall time", "", f"{doc['cpus']} CPUs ({doc['machine']}); goal: <= 300 s.", "",
             "| run | wall (s) | passed | per check (s) |", "|---|---|---|---|"]
    lines += [f"| {r['run']} | {r['wall_s']} | {r['passed']} | "
              + ", ".join(f"{k} {v}" for k, v in r["checks_s"].items()) + " |" for r in rows]
    (args.out / "gate_speed.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
