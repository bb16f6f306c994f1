"""``workbench score``: another tool's results (or an engine run) against the truth."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.commands.options import positive_int_arg, strain_window_arg


def add_parser(sub) -> None:
    """The ``score`` subcommand."""
    from workbench.readers.conventions import MEASURES, SHEARS, UNITS
    from workbench.results import LENGTH_UNITS_MM, PIXEL_ORIGINS, READERS
    from workbench.scoring.metrics import ALIGNMENTS

    sc = sub.add_parser("score", help="score another tool's result files (or an engine run) against the truth")
    sc.add_argument("dataset", type=Path, help="the dataset folder or scenario file the results were computed on")
    sc.add_argument("results", type=Path, nargs="*", help="result files, one per deformed state: a `workbench stereo` "
                         "result is scored against the state of the images it measured (its manifest.json says which); "
                         "another file's state is the number its name ends with (0 = the reference), or --state")
    sc.add_argument("--format", choices=READERS, default=None,
                    help="result file format (default: the engine's, csv with --columns, else auto: recognised from "
                         "the header)")
    sc.add_argument("--columns", default=None, help="for --format csv: x=COL,y=COL,u=COL,v=COL[,X=..,Y=..,Z=..,"
                                                    "U=..,V=..,W=..,valid=COL]")
    sc.add_argument("--pixel-origin", choices=tuple(PIXEL_ORIGINS), default="center",
                    help="the tool's pixel coordinates: center (OpenCV, integer centres), corner (0 at the pixel's "
                         "corner), one-based (MATLAB)")
    sc.add_argument("--length-unit", choices=tuple(LENGTH_UNITS_MM), default="mm", help="unit of 3-D columns")
    sc.add_argument("--state", type=positive_int_arg, default=None, help="the deformed state of a single result file")
    sc.add_argument("--align", choices=ALIGNMENTS, default="none",
                    help="3-D frame: none (the tool reports the left camera frame) or rigid (one rigid fit of its "
                         "reference positions onto the truth)")
    sc.add_argument("--engine", default=None, help="run this engine on the left images of every deformed state "
                                                   "first: 'cmd {ref} {def} {out}' or module:function")
    sc.add_argument("--subset", type=positive_int_arg, default=33, help="subset size passed to --engine, px")
    sc.add_argument("--step", type=positive_int_arg, default=8, help="step passed to --engine, px")
    sc.add_argument("--strain-measure", choices=MEASURES, default=None,
                    help="what the file's strain columns are, where the file does not say (VIC-3D, MatchID, "
                         "OpenCorr, csv): with --strain-shear and --strain-unit; converted to Green-Lagrange")
    sc.add_argument("--strain-shear", choices=SHEARS, default=None,
                    help="the xy strain column: the tensor component or the engineering shear (twice it)")
    sc.add_argument("--strain-unit", choices=tuple(UNITS), default=None, help="unit of the strain columns")
    sc.add_argument("--ignore-strain", action="store_true",
                    help="score the displacements only, leaving a file's strain columns unread")
    sc.add_argument("--strain-window", type=strain_window_arg, default=None, metavar="K|triangles",
                    help="the strain window the tool used, in grid points per side (or 'triangles'): the truth is "
                         "put through the same window; default: what the result's manifest says (workbench stereo)")
    sc.add_argument("--strain-fit", choices=("linear", "quadratic"), default="linear",
                    help="the order of the tool's strain-window fit (with --strain-window), default linear")
    sc.add_argument("--line", action="append", default=[], metavar="X0,Y0,X1,Y1",
                    help="a line of the left reference image (px) to profile the strain along, against the truth "
                         "(e.g. through a hole or a notch root); may be given several times")
    sc.add_argument("--extensometer", action="append", default=[], metavar="X0,Y0,X1,Y1",
                    help="a virtual extensometer between two points of the left reference image (px): the change of "
                         "their distance measured vs the truth, per state; may be given several times")
    sc.add_argument("--mask", type=Path, default=None,
                    help="image of the left reference's size: only points whose reference pixel is non-zero in it are "
                         "scored (your ROI)")
    sc.add_argument("--store", type=Path, default=None, help="render store (default $WORKBENCH_STORE)")
    sc.add_argument("--out", type=Path, required=True)



def _states_of(dataset, paths: list[Path], state: int | None, fmt: str = "auto") -> list[tuple[int, Path]]:
    """The dataset state of each result file: the state of the images the file says it measured (a ``workbench
    stereo`` result, whatever its name), else ``--state``, else the number its name ends with (state 0 is the
    reference in every file of this project: ``state_001.csv`` is the first deformed state; VIC-3D's and MatchID's
    files end with the camera's index after it: ``dataset-0002_0.csv`` is state 2)."""
    from workbench.results import measured_images, state_of
    from workbench.scoring.datasets import state_of_images

    if state is not None and len(paths) != 1:
        raise ValueError(f"--state names the state of one result file, got {len(paths)} files")
    out = []
    for p in paths:
        measured = measured_images(p)
        if measured is not None:
            k = state_of_images(dataset, measured)
            if state is not None and state != k:
                raise ValueError(f"--state {state}: {p} measured the images of state {k} "
                                 f"({', '.join(Path(str(v)).name for v in measured.state.values())}), says "
                                 f"{measured.record}")
            how = f"its images are state {k}'s ({measured.record.name})"
        elif state is not None:
            k, how = state, "--state"
        elif len(paths) == 1 and dataset.n_states == 2:
            k, how = 1, "the dataset's one deformed state"
        else:
            layout = fmt
            if fmt == "auto":
                from workbench.results import detect_format
                try:
                    layout = detect_format(p)
                except ValueError:
                    layout = None               # read_result says what is wrong with it, naming the file
            k = state_of(p, layout)
            if k is None:
                raise ValueError(f"{p}: the file name ends with no state number; give --state")
            how = "the number its name ends with"
        if k == 0:
            if len(paths) > 1:
                print(f"  {p}: state 0 is the reference (nothing to score), left out ({how})")
                continue
            raise ValueError(f"{p} is the result of state 0, the reference ({how}): nothing to score")
        out.append((k, p))
    ks = [k for k, _ in out]
    twice = sorted({k for k in ks if ks.count(k) > 1})
    if twice:
        raise ValueError(f"several result files give state {twice[0]}: "
                         f"{', '.join(str(p) for k, p in out if k == twice[0])}")
    return sorted(out)


def _user_mask(path: Path, dataset) -> np.ndarray:
    """The user's mask as a bool image of the dataset's left reference size; refused naming both sizes."""
    from workbench.commands.options import read_image_for, size_text

    image = read_image_for(path, "--mask")
    w, h = dataset.image_size_px
    if image.shape[:2] != (h, w):
        raise ValueError(f"--mask {path} is {size_text(image)} but the dataset's images are {w} x {h} px")
    return image != 0 if image.ndim == 2 else np.any(image != 0, axis=-1)


def _inside_mask(result, mask: np.ndarray):
    """The result restricted to the points whose reference pixel (nearest) is non-zero in ``mask``, and how many
    points were left out."""
    from dataclasses import replace

    h, w = mask.shape
    col = np.rint(np.nan_to_num(result.x_px, nan=-1.0)).astype(np.int64)
    row = np.rint(np.nan_to_num(result.y_px, nan=-1.0)).astype(np.int64)
    inside = (col >= 0) & (row >= 0) & (col < w) & (row < h)
    inside[inside] = mask[row[inside], col[inside]]
    fields = {name: getattr(result, name)[inside] for name in
              ("x_px", "y_px", "valid", "u_px", "v_px", "X_mm", "U_mm", "strain", "sigma_uv_px", "sigma_U_mm",
               "surface_strain", "surface_strain_sigma") if getattr(result, name) is not None}
    return replace(result, **fields), int((~inside).sum())


def _results_by_state(dataset, paths: list[Path], args, fmt: str, convention) -> list[tuple[int, Path, object]]:
    """(state, file, ToolResult) of every result to score: a file of every state (Ncorr, MultiDIC) gives one per
    state it holds; any other file is one state (:func:`_states_of`). Every file is read before any is scored."""
    from workbench.results import MULTI_STATE, detect_format, read_result, read_results

    single, out = [], []
    for p in paths:
        layout = detect_format(p) if fmt == "auto" and p.is_file() and p.suffix.lower() == ".mat" else fmt
        if layout in MULTI_STATE:
            for r in read_results(p, layout):
                if not 1 <= r.state < dataset.n_states:
                    raise ValueError(f"{p}: holds state {r.state}, but {dataset.folder} has states 1 to "
                                     f"{dataset.n_states - 1}")
                if args.state is None or args.state == r.state:
                    out.append((r.state, p, r))
        else:
            single.append(p)
    for state, path in _states_of(dataset, single, args.state, fmt) if single else []:
        out.append((state, path, read_result(path, fmt, args.columns, args.pixel_origin, args.length_unit,
                                             convention, args.ignore_strain)))
    states = [k for k, _, _ in out]
    twice = sorted({k for k in states if states.count(k) > 1})
    if twice:
        raise ValueError(f"several results give state {twice[0]}: "
                         f"{', '.join(str(p) for k, p, _ in out if k == twice[0])}")
    return sorted(out, key=lambda item: item[0])


def score_command(args) -> int:
    from workbench.scoring.datasets import open_dataset, point_truth, subset_roi_xyxy_px
    from workbench.engines import parse_engine, run_engine
    from workbench.scoring.metrics import score_state
    from workbench.scoring.probes import extensometer, parse_segment
    from workbench.scoring.report import write_score_report

    from workbench.readers.conventions import convention_from_options

    convention = convention_from_options(args.strain_measure, args.strain_shear, args.strain_unit)
    lines = [parse_segment(t, "--line") for t in args.line]
    gauges = [parse_segment(t, "--extensometer") for t in args.extensometer]
    window = None
    if args.strain_window is not None:
        window = {"window_points": None if args.strain_window == "triangles" else args.strain_window,
                  "fit": args.strain_fit}
    dataset = open_dataset(args.dataset, args.store)
    mask = _user_mask(args.mask, dataset) if args.mask is not None else None
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
    fmt = fmt or ("csv" if args.columns else "auto")        # a column mapping is for a CSV of any layout
    scores, tool = [], None
    extensometers = {g: [] for g in gauges}
    gauge_truth = {g: point_truth(dataset, [g[0], g[2]], [g[1], g[3]]) for g in gauges}
    for g, t in gauge_truth.items():
        if not t.valid.all():
            raise ValueError(f"--extensometer {','.join(f'{v:g}' for v in g)}: an end does not see the specimen in the "
                             "left reference image")
    for state, path, result in _results_by_state(dataset, paths, args, fmt, convention):
        tool = tool or result.tool
        if mask is not None:
            result, outside = _inside_mask(result, mask)
            if not result.x_px.size:
                raise ValueError(f"{path}: no point of the result lies inside --mask {args.mask}")
        s = score_state(dataset, state, result, args.align, window)
        if mask is not None:
            s.metrics["outside_mask_points"] = outside
        for g in gauges:
            if result.X_mm is None:
                raise ValueError(f"--extensometer needs 3-D positions; {path} has none")
            extensometers[g].append(extensometer(result, gauge_truth[g], state, g))
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
        if "strain_peak_e1_windowed_microstrain" in m:
            line += (f"; strain e1 error RMS {m['strain_rms_e1_vs_windowed_microstrain']:.3g} µε vs the windowed truth, "
                     f"peak {m['strain_peak_e1_measured_microstrain']:.0f} µε measured / "
                     f"{m['strain_peak_e1_windowed_microstrain']:.0f} windowed / "
                     f"{m.get('strain_peak_e1_exact_microstrain', float('nan')):.0f} exact")
        print(line)
    doc = write_score_report(args.out, dataset, scores, tool or fmt, paths, notes, lines=lines,
                             extensometers=extensometers, mask=None if args.mask is None else str(args.mask),
                             progress=print)
    print(f"wrote {args.out / 'report.html'}, report.md and metrics.json")
    return 0 if doc["states"] else 1


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("score", None): score_command}
