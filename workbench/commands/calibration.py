"""``workbench calibration convert``: calibration files between formats."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.commands.options import pair_arg


def add_parser(sub) -> None:
    """The ``calibration`` subcommand."""
    cal_files = sub.add_parser("calibration", help="calibration files: convert between formats")
    cal_sub = cal_files.add_subparsers(dest="what", required=True)
    conv = cal_sub.add_parser("convert", help="calibration files between this project's JSON, OpenCV YAML/XML, DICe "
                                              "cal.xml, VIC-3D XML, MatchID .caldat and MATLAB stereoParameters "
                                              "(toStruct as JSON or .mat); says what the target costs")
    conv.add_argument("source", type=Path, help="any of those (the format is detected from the content)")
    conv.add_argument("target", type=Path, help="output file (written atomically)")
    conv.add_argument("--to", choices=("json", "opencv", "dice", "vic3d", "matchid", "matlab"), default=None,
                      help="target format (default from the suffix: .json json, .yaml/.yml/.xml opencv, .cal vic3d, "
                           ".caldat matchid, .mat matlab; a MATLAB JSON needs --to matlab)")
    conv.add_argument("--image-size", type=pair_arg, default=None, metavar="W,H",
                      help="image size of a source that holds none (MatchID .caldat), px")
    conv.add_argument("--frame-rotation", action="store_true",
                      help="let a format without the paper's tilt absorb it in a rotation of the camera frames")


_SUFFIX_FORMAT = {".json": "json", ".yaml": "opencv", ".yml": "opencv", ".xml": "opencv", ".cal": "vic3d",
                  ".caldat": "matchid", ".mat": "matlab"}


def calibration_convert_command(args) -> int:
    from measurement.calibration.formats import load_any_calibration, save_calibration_as
    from measurement.calibration.io import opencv_distortion_cost_px

    fmt = args.to or _SUFFIX_FORMAT.get(args.target.suffix.lower())
    if fmt is None:
        raise ValueError(f"{args.target}: say the target format with --to (json, opencv, dice, vic3d, matchid) or "
                         f"--to matlab; "
                         f"the suffix {args.target.suffix or '(none)'} does not")
    if args.target.resolve() == args.source.resolve():
        raise ValueError(f"{args.target}: the target is the source file")
    size = None if args.image_size is None else (int(args.image_size[0]), int(args.image_size[1]))
    rig = load_any_calibration(args.source, image_size_px=size)
    report = save_calibration_as(rig, args.target, fmt, frame_rotation=args.frame_rotation)
    back = load_any_calibration(args.target, image_size_px=(rig.left.width, rig.left.height))
    print(f"wrote {args.target} as {fmt} ({rig.model} rig, {rig.left.width} x {rig.left.height} px) from {args.source}")
    for c in report.cameras:
        state = "exactly" if c.exact else f"within {c.mean_px:.3g} px mean, {c.max_px:.3g} px max"
        print(f"  {c.side}: written as {c.model}: it projects the source camera {state} over the image")
        for n in c.notes:
            print(f"    - {n}")
    for n in report.notes:
        print(f"  - {n}")
    if fmt in ("json", "opencv") and not args.frame_rotation:
        for side in ("left", "right"):
            a, b = getattr(rig, side), getattr(back, side)
            u, v = np.meshgrid(np.linspace(0, a.width - 1, 11), np.linspace(0, a.height - 1, 11))
            X = a.rays(np.column_stack([u.ravel(), v.ravel()])) * 400.0
            moved = float(np.nanmax(np.linalg.norm(a.project(X) - b.project(X), axis=1)))
            line = f"  {side}: the converted camera reprojects within {moved:.2g} px of the source"
            if fmt == "opencv":
                cost = opencv_distortion_cost_px(a)
                line += (f"; a tool that reads only K{1 if side == 'left' else 2}/D{1 if side == 'left' else 2} "
                         + ("projects it exactly (OpenCV's tilted model expresses it)" if cost < 1e-6 else
                            f"misses by up to {cost:.3g} px (the paper's two-axis RMM tilt is not OpenCV's tilt)"))
            print(line)
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("calibration", "convert"): calibration_convert_command}
