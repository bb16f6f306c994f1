"""``workbench export`` and ``workbench score``: other DIC tools on the workbench's datasets."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def add_parsers(sub, positive_int) -> None:
    """The ``export`` and ``score`` subcommands."""
    from workbench.export import FORMATS
    from workbench.results import LENGTH_UNITS_MM, PIXEL_ORIGINS, READERS
    from workbench.scoring import ALIGNMENTS

    ex = sub.add_parser("export", help="write a rendered dataset as another DIC tool reads it (images, calibration, "
                                       "truth)")
    ex.add_argument("dataset", type=Path, help="a dataset folder (render store, render command) or a scenario "
                                               "file (.toml/.json), rendered through the store first")
    ex.add_argument("--format", choices=FORMATS, default="native")
    ex.add_argument("--subset", type=positive_int, default=33, help="subset size written into the tool's input, px")
    ex.add_argument("--step", type=positive_int, default=8, help="step written into the tool's input, px")
    ex.add_argument("--grid-step", type=positive_int, default=8, help="spacing of the truth grid of points.csv, px")
    ex.add_argument("--truth-step", type=positive_int, default=1, help="spacing of the per-pixel truth array, px")
    ex.add_argument("--frame-rotation", action="store_true",
                    help="let the calibration absorb a Scheimpflug tilt the format lacks in a rotation of the camera "
                         "frames (exact for DICe's OpenCV tilt); the extrinsics carry it")
    ex.add_argument("--store", type=Path, default=None, help="render store (default $WORKBENCH_STORE)")
    ex.add_argument("--out", type=Path, required=True, help="a new folder")

    sc = sub.add_parser("score", help="score another tool's result files (or an engine run) against the truth")
    sc.add_argument("dataset", type=Path, help="the dataset folder or scenario file the results were computed on")
    sc.add_argument("results", type=Path, nargs="*", help="result files, one per deformed state (the state is the "
                                                          "number the file name ends with, or --state)")
    sc.add_argument("--format", choices=READERS, default=None,
                    help="result file format (default: the engine's, else native)")
    sc.add_argument("--columns", default=None, help="for --format csv: x=COL,y=COL,u=COL,v=COL[,X=..,Y=..,Z=..,"
                                                    "U=..,V=..,W=..,valid=COL]")
    sc.add_argument("--pixel-origin", choices=tuple(PIXEL_ORIGINS), default="center",
                    help="the tool's pixel coordinates: center (OpenCV, integer centres), corner (0 at the pixel's "
                         "corner), one-based (MATLAB)")
    sc.add_argument("--length-unit", choices=tuple(LENGTH_UNITS_MM), default="mm", help="unit of 3-D columns")
    sc.add_argument("--state", type=positive_int, default=None, help="the deformed state of a single result file")
    sc.add_argument("--align", choices=ALIGNMENTS, default="none",
                    help="3-D frame: none (the tool reports the left camera frame) or rigid (one rigid fit of its "
                         "reference positions onto the truth)")
    sc.add_argument("--engine", default=None, help="run this engine on the left images of every deformed state "
                                                   "first: 'cmd {ref} {def} {out}' or module:function")
    sc.add_argument("--subset", type=positive_int, default=33, help="subset size passed to --engine, px")
    sc.add_argument("--step", type=positive_int, default=8, help="step passed to --engine, px")
    sc.add_argument("--store", type=Path, default=None, help="render store (default $WORKBENCH_STORE)")
    sc.add_argument("--out", type=Path, required=True)


def add_gate_parser(sub) -> None:
    gt = sub.add_parser("gate", help="accuracy regression gate: a quick fixed suite vs thresholds and a baseline "
                                     "(table, gate.md, JUnit XML; exit 1 on a regression)")
    gt.add_argument("gate_file", type=Path, help="gate file (TOML), e.g. gates.toml")
    gt.add_argument("--engine", default=None, help="2-D engine for the 2-D checks: 'cmd {ref} {def} {out}' or "
                                                   "module:function (default: this project's instrument)")
    gt.add_argument("--baseline", type=Path, default=None, help="baseline JSON (default: the gate file's)")
    gt.add_argument("--junit", type=Path, default=None, help="write JUnit XML here")
    gt.add_argument("--update-baseline", action="store_true",
                    help="write the measured values as the new baseline instead of comparing")
    gt.add_argument("--store", type=Path, default=None, help="render store (default $WORKBENCH_STORE)")
    gt.add_argument("--out", type=Path, required=True)


def gate_command(args) -> int:
    from workbench.gate import gate_command as run
    return run(args)


def export_command(args) -> int:
    from workbench.datasets import open_dataset
    from workbench.export import ExportSettings, export_dataset

    dataset = open_dataset(args.dataset, args.store)
    settings = ExportSettings(subset_px=args.subset, step_px=args.step, grid_step_px=args.grid_step,
                              truth_step_px=args.truth_step)
    record = export_dataset(dataset, args.format, args.out, settings, frame_rotation=args.frame_rotation)
    print(f"wrote {args.out} ({record['seconds']:.1f} s): see {args.out / 'export.json'}")
    return 0


def _states_of(dataset, paths: list[Path], state: int | None) -> list[tuple[int, Path]]:
    from workbench.results import state_of

    if state is not None:
        if len(paths) != 1:
            raise ValueError(f"--state names the state of one result file, got {len(paths)} files")
        return [(state, paths[0])]
    if len(paths) == 1 and dataset.n_states == 2:
        return [(1, paths[0])]
    out = []
    for p in paths:
        k = state_of(p)
        if k is None:
            raise ValueError(f"{p}: the file name ends with no state number; give --state")
        if k == 0 and len(paths) > 1:
            print(f"  {p}: state 0 is the reference (nothing to score), left out")
            continue
        out.append((k, p))
    return sorted(out)


def score_command(args) -> int:
    from workbench.datasets import open_dataset, subset_roi_xyxy_px
    from workbench.engines import parse_engine, run_engine
    from workbench.results import read_result
    from workbench.scoring import score_state, write_score_report

    dataset = open_dataset(args.dataset, args.store)
    notes = []
    fmt = args.format
    paths = list(args.results)
    if args.engine:
        if paths:
            raise ValueError("give result files or --engine, not both")
        engine = parse_engine(args.engine)
        fmt = fmt or engine.result_format or "native"
        roi = subset_roi_xyxy_px(dataset, args.subset)
        runs = args.out / "engine"
        for k in range(1, dataset.n_states):
            target = runs / f"result_{k:02d}.csv"
            info = run_engine(engine, dataset.images[0]["left"], dataset.images[k]["left"], target,
                              subset_px=args.subset, step_px=args.step, roi_xyxy_px=roi)
            print(f"  state {k} ({dataset.labels[k]}): engine ran in {info['seconds']:.1f} s")
            paths.append(target)
        notes.append(f"engine: {args.engine} (subset {args.subset} px, step {args.step} px, ROI {roi}) on the left "
                     "images (2-D)")
    if not paths:
        raise ValueError("no result files and no --engine")
    fmt = fmt or "native"
    scores, tool = [], None
    for state, path in _states_of(dataset, paths, args.state):
        result = read_result(path, fmt, args.columns, args.pixel_origin, args.length_unit)
        tool = tool or result.tool
        s = score_state(dataset, state, result, args.align)
        scores.append(s)
        m = s.metrics
        line = f"state {state} ({m['label']}): {m['valid_points']}/{m['truth_points']} points scored"
        if m["not_measured_points"]:
            line += f" ({m['not_measured_points']} not measured: NaN or flagged by the tool, left out)"
        if m["rows_without_position"]:
            line += f"; {m['rows_without_position']} rows without a finite x, y left out"
        if m["valid_points"] == 0:
            line += "; no point on the specimen to score"
        elif "bias_u_px" in m:
            line += f", u bias {m['bias_u_px']:+.4f} px rms {m['rms_u_px']:.4f}, v bias {m['bias_v_px']:+.4f} rms {m['rms_v_px']:.4f}"
        if m["valid_points"] and "bias_U_um" in m:
            line += f", 3-D error rms {m['rms_um']:.3g} µm (max {m['max_um']:.3g})"
        if "frame_hint" in m:
            notes.append(f"state {state}: {m['frame_hint']}")
            print(f"  warning: {m['frame_hint']}")
        if m["outside_points"]:
            line += f"; {m['outside_points']} points off the specimen left out"
        print(line)
    doc = write_score_report(args.out, dataset, scores, tool or fmt, paths, notes)
    print(f"wrote {args.out / 'report.md'} and {args.out / 'metrics.json'}")
    return 0 if doc["states"] else 1
