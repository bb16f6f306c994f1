"""``workbench gate``: the accuracy regression gate."""
from __future__ import annotations

from pathlib import Path


def add_parser(sub) -> None:
    """The ``gate`` subcommand."""
    gt = sub.add_parser("gate", help="accuracy regression gate: a quick fixed suite vs thresholds and a baseline "
                                     "(table, gate.md, JUnit XML; exit 1 on a regression)")
    gt.add_argument("gate_file", type=Path, help="gate file (TOML), e.g. gates.toml")
    gt.add_argument("--engine", default=None, help="2-D engine for the 2-D checks: 'cmd {ref} {def} {out}' or "
                                                   "module:function (default: this project's instrument)")
    gt.add_argument("--baseline", type=Path, default=None, help="baseline JSON (default: the gate file's)")
    gt.add_argument("--junit", type=Path, default=None, help="write JUnit XML here")
    gt.add_argument("--update-baseline", action="store_true",
                    help="write the measured values as the new baseline instead of comparing")
    gt.add_argument("--require-current-baseline", action="store_true",
                    help="fail when the baseline was not measured by this checkout's code (a source file that "
                         "measured it has changed since, or it records none); without it the gate only says so")
    gt.add_argument("--store", type=Path, default=None, help="render store (default $WORKBENCH_STORE)")
    gt.add_argument("--out", type=Path, required=True)


def gate_command(args) -> int:
    from workbench.scoring.gate import gate_command as run
    return run(args)


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("gate", None): gate_command}
