"""The ``workbench`` command line.

    workbench render checkerboard --rig paper --views N --seed S [--scale F] [--spp N] [--overwrite] --out DIR
    workbench render specimen SCENARIO.toml [--overwrite] --out DIR    (a mesh or FE file of one's own)
    workbench catalog plate_with_hole|notched_coupon|pressurised_cylinder|beam [--scale F] --out DIR
    workbench reproduce agreement [--rig paper] [--views N] [--scale F] [--spp N] [--seed S] --out DIR
    workbench reproduce depth-of-field [--scale F] [--f-number N] [--spp N] --out DIR
    workbench reproduce calibration [--scale F] [--seed S] [--spp N] --out DIR
    workbench calibrate --left GLOB --right GLOB --square-mm 5 --pattern 11x8 [--model rmm]
                        [--tilt-guess-deg A,B] --out calib.json
    workbench reproduce dic-accuracy --out DIR
    workbench reproduce paper [--quick] [--scale F] [--mc-target-grey G] [--strict] --out DIR
    workbench reproduce rigid-motion [--scale F] [--calib rendered|true|FILE] [--lens thin|pinhole] --out DIR
    workbench stereo --calib calib.json --left-ref L0 --right-ref R0 --left GLOB --right GLOB [--roi ...]
                     [--subset 65] [--step 5] [--max-residual-px 0.5] [--min-measured-fraction 0.5]
                     [--overwrite] --out DIR
    workbench dic REF DEF [--roi X0,Y0,X1,Y1] [--subset 33] [--step 8] [--order 1|2]
                  [--interp biquintic|bicubic] [--seed-point X,Y] --out points.csv
    workbench sweep STUDY.toml [--scheduler tcp://HOST:8786] [--workers N] [--store DIR] --out DIR
    workbench budget STUDY.toml --metric NAME [--at DIM=VALUE] [--scheduler ...] [--workers N] --out DIR
    workbench parameters            (every scenario.* and instrument.* parameter a study may set)
    workbench reproduce fig6-causes [--study studies/fig6_causes.toml] [--workers N] --out DIR
    workbench twin [--calib CAL] --left L0 [--right R0] [--static-left L1 --static-right R1]
                   [--roi ...|--mask M|--auto-roi] [--subset 33] [--step 8] [--order 2] [--strain-window 5] --out DIR

Every option is checked when it is parsed (numbers finite and in range, sizes odd, ...) and every input file
before the first long computation; errors are one line naming the option or file, exit code 2. Files are
written atomically (:mod:`labio.atomic`); dataset folders carry a manifest (:mod:`workbench.manifest`).

Each verb is one module of :mod:`workbench.commands` (its parser and its handler); this module assembles them.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import warnings

from labio.memory import keep_freed_memory

from workbench.commands import (budget, calibrate, calibration, catalog, design, dic, export, gate, parameters,
                                render, reproduce, score, stereo, sweep, twin)

#: The verbs in the order ``workbench --help`` lists them.
VERBS = (render, reproduce, calibrate, stereo, dic, sweep, budget, export, score, gate, parameters, calibration,
         catalog, twin, design)
#: (command, subcommand or None) -> handler(args) -> exit code, from every verb's module.
HANDLERS = {key: handler for verb in VERBS for key, handler in verb.HANDLERS.items()}


def parser() -> argparse.ArgumentParser:
    """The ``workbench`` parser: each verb's module adds its own subcommand."""
    p = argparse.ArgumentParser(prog="workbench", description="Scheimpflug stereo-DIC virtual lab.")
    sub = p.add_subparsers(dest="command", required=True)
    for verb in VERBS:
        verb.add_parser(sub)
    return p


@contextlib.contextmanager
def _one_line_warnings(where: str):
    """Warnings print as ``workbench CMD: warning: ...`` (no source line), as errors do."""
    previous = warnings.formatwarning
    warnings.formatwarning = lambda message, category, *rest: f"{where}: warning: {message}\n"
    try:
        yield
    finally:
        warnings.formatwarning = previous


#: Options whose value is a comma-separated list of numbers (may start with a minus sign).
_LIST_OPTIONS = ("--roi", "--seed-point", "--seed-guess", "--tilt-guess-deg", "--tilt-guess-right-deg")


def _join_negative_lists(argv: list[str]) -> list[str]:
    """``--seed-guess -3,2`` as ``--seed-guess=-3,2``: argparse would take ``-3,2`` for an option and say
    "expected one argument"."""
    out, k = [], 0
    while k < len(argv):
        token = argv[k]
        if token in _LIST_OPTIONS and k + 1 < len(argv) and argv[k + 1].startswith("-") \
                and not argv[k + 1].startswith("--") and "," in argv[k + 1]:
            out.append(f"{token}={argv[k + 1]}")
            k += 2
            continue
        out.append(token)
        k += 1
    return out


def main(argv: list[str] | None = None) -> int:
    keep_freed_memory()      # image-sized blocks reused, not faulted in again page by page (labio.memory)
    argv = _join_negative_lists(list(sys.argv[1:] if argv is None else argv))
    try:
        args = parser().parse_args(argv)
    except SystemExit as exit_:          # argparse: --help (0) or a refused option (2, message printed)
        return exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 2)
    where = " ".join(filter(None, ("workbench", args.command, getattr(args, "what", None))))
    try:
        with _one_line_warnings(where):
            return HANDLERS[(args.command, getattr(args, "what", None))](args)
    except (ValueError, OSError, RuntimeError) as err:
        # Bad input and missing system pieces get one clear line, never a traceback.
        print(f"{where}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{where}: interrupted (files already written are whole; a dataset without manifest.json is "
              "incomplete)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
