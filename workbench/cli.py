"""The ``workbench`` command line.

    workbench render checkerboard --rig paper --views N --seed S [--scale F] [--spp N] [--overwrite] --out DIR
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

Every option is checked when it is parsed (numbers finite and in range, sizes odd, ...) and every input file
before the first long computation; errors are one line naming the option or file, exit code 2. Files are
written atomically (:mod:`measurement.files`); dataset folders carry a manifest (:mod:`workbench.manifest`).
"""
from __future__ import annotations

import argparse
import contextlib
import math
import sys
import warnings
from pathlib import Path

import numpy as np

#: Renders derive 32-bit sampler seeds as ``seed * 100003 + 2 * view + camera``: seeds up to this fit.
MAX_SEED = (2 ** 32 - 1) // 100003 - 1
#: Most views one checkerboard render may hold (keeps the derived sampler seeds in 32 bits).
MAX_VIEWS = 10_000


# ------------------------------------------------------------------------------------------------------------
# Option parsers: argparse prints "argument --NAME: <message>" and exits 2 for an ArgumentTypeError.
def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def _positive_int(text: str) -> int:
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _views(text: str) -> int:
    value = _positive_int(text)
    if value > MAX_VIEWS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_VIEWS}, got {value}")
    return value


def _seed(text: str) -> int:
    value = _integer(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, {MAX_SEED}] (renders derive 32-bit sampler "
                                         f"seeds from it), got {value}")
    return value


def _subset(text: str) -> int:
    value = _integer(text)
    if value < 5 or value % 2 == 0:
        raise argparse.ArgumentTypeError(f"must be odd and >= 5 (a subset is 2M + 1 pixels wide), got {value}")
    return value


def _positive_float(text: str) -> float:
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _non_negative_float(text: str) -> float:
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def _zncc(text: str) -> float:
    value = _number(text)
    if not -1.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"a ZNCC threshold must be in [-1, 1], got {text!r}")
    return value


def _fraction(text: str) -> float:
    value = _number(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1], got {text!r}")
    return value


def _scale(text: str) -> float:
    value = _number(text)
    if not 0 < value <= 4:
        raise argparse.ArgumentTypeError(f"scale must be in (0, 4], got {value}")
    return value


def _angle_deg(text: str) -> float:
    value = _number(text)
    if not -80.0 <= value <= 80.0:
        raise argparse.ArgumentTypeError(f"must be an angle in [-80, 80] deg, got {text!r}")
    return value


def _pattern(text: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"pattern must look like 11x8, got {text!r}") from None
    if a < 2 or b < 2:
        raise argparse.ArgumentTypeError(f"pattern needs at least 2x2 inner corners, got {text!r}")
    return a, b


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two numbers 'A,B', got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise argparse.ArgumentTypeError(f"expected two finite numbers 'A,B', got {text!r}")
    return a, b


def _tilt_pair(text: str) -> tuple[float, float]:
    a, b = _pair(text)
    if max(abs(a), abs(b)) > 45.0:
        raise argparse.ArgumentTypeError(f"sensor tilts (alpha,beta) must be within +-45 deg, got {text!r}")
    return a, b


def _roi(text: str) -> tuple[int, int, int, int]:
    try:
        numbers = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"roi must be four numbers X0,Y0,X1,Y1 (px), got {text!r}") from None
    if len(numbers) != 4:
        raise argparse.ArgumentTypeError(f"roi must be four numbers X0,Y0,X1,Y1 (px), got {text!r}")
    if not all(math.isfinite(v) for v in numbers):
        raise argparse.ArgumentTypeError(f"roi must be four finite numbers X0,Y0,X1,Y1 (px), got {text!r}")
    x0, y0, x1, y1 = (int(round(v)) for v in numbers)
    if min(x0, y0) < 0 or x1 <= x0 or y1 <= y0:
        raise argparse.ArgumentTypeError(f"roi needs 0 <= X0 < X1 and 0 <= Y0 < Y1 (px), got {text!r}")
    return x0, y0, x1, y1


# ------------------------------------------------------------------------------------------------------------
# Checks on files and folders, run before any long computation.
def _input_file(path: Path, what: str) -> Path:
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what} {path} is a directory, not a file")
    if not path.is_file():
        raise ValueError(f"{what} not found: {path}")
    return path


def _existing_ancestor_is_folder(path: Path, what: str) -> None:
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{what} {path}: {parent} is a file, not a folder")
            return


def _output_file(path: Path, what: str = "--out") -> Path:
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what} {path} is a directory; give the name of the file to write")
    _existing_ancestor_is_folder(path, what)
    return path


def _output_folder(path: Path, what: str = "--out") -> Path:
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{what} {path} is a file, not a folder")
    _existing_ancestor_is_folder(path, what)
    return path


def _glob_files(pattern: str, option: str) -> list[str]:
    import glob

    matches = sorted(glob.glob(pattern))
    if not matches:
        raise ValueError(f"no images match {option} {pattern!r}")
    folders = [m for m in matches if Path(m).is_dir()]
    if folders:
        raise ValueError(f"{option} {pattern!r} matches the directory {folders[0]}; give a pattern of image files")
    return matches


def _paired_globs(left_pattern: str, right_pattern: str) -> tuple[list[str], list[str]]:
    left, right = _glob_files(left_pattern, "--left"), _glob_files(right_pattern, "--right")
    if len(left) != len(right):
        raise ValueError(f"{len(left)} left images but {len(right)} right images: they must pair up "
                         f"(--left {left_pattern!r}, --right {right_pattern!r})")
    same = sorted(set(map(_resolved, left)) & set(map(_resolved, right)))
    if same:
        raise ValueError(f"--left and --right both match {same[0]}: left and right images must be different files")
    return left, right


def _resolved(path) -> str:
    return str(Path(path).resolve())


def _size(image: np.ndarray) -> str:
    return f"{image.shape[1]} x {image.shape[0]} px"


def _read_image(path, what: str):
    """An image through the one loader, after checking the path is a file (a directory says so)."""
    from measurement.image_io import read_grey

    return read_grey(_input_file(Path(path), what))


def _check_subset_fits(subset: int, image: np.ndarray, what: str = "image") -> None:
    if subset > min(image.shape):
        raise ValueError(f"--subset {subset} px does not fit the {_size(image)} {what}: it must be at most "
                         f"{min(image.shape)} px (the image's smaller side)")


def _check_roi_in_image(roi, image: np.ndarray, what: str = "image") -> None:
    if roi is None:
        return
    x0, y0, x1, y1 = roi
    h, w = image.shape
    if x1 > w or y1 > h:
        raise ValueError(f"--roi {x0},{y0},{x1},{y1} reaches outside the {_size(image)} {what} "
                         f"(need X1 <= {w}, Y1 <= {h})")


def _poi_grid(image: np.ndarray, args, mask=None, what: str = "image"):
    """The POI grid of the options, with errors that name the option the user gave (never an implicit ROI)."""
    from measurement.dic import poi_grid

    _check_subset_fits(args.subset, image, what)
    _check_roi_in_image(args.roi, image, what)
    try:
        return poi_grid(image.shape, args.subset, args.step, roi=args.roi, mask=mask)
    except ValueError as err:
        if args.roi is not None:
            raise ValueError(f"--roi {','.join(map(str, args.roi))}: {err}") from None
        if mask is not None:
            raise ValueError(f"--mask: {err}") from None
        raise ValueError(f"--subset {args.subset} px leaves no point of interest in the {_size(image)} {what} "
                         f"({err})") from None


def _auto_roi_options(parser) -> None:
    """``--auto-roi-precision`` and ``--noise-sigma`` of the ``dic`` and ``stereo`` commands (need ``--auto-roi``)."""
    from measurement.dic.roi import DEFAULT_TARGET_PRECISION_PX

    parser.add_argument("--auto-roi-precision", type=_positive_float, default=None,
                        help="with --auto-roi: largest noise-limited std of u, v a subset must reach (px), default "
                             f"{DEFAULT_TARGET_PRECISION_PX:g}")
    parser.add_argument("--noise-sigma", type=_non_negative_float, default=None,
                        help="with --auto-roi: image noise std (grey levels), default estimated from the reference")


def _auto_roi(args):
    """The :class:`measurement.dic.roi.AutoRoi` of the options, None without ``--auto-roi`` (whose options then
    are an error)."""
    from measurement.dic.roi import DEFAULT_TARGET_PRECISION_PX, AutoRoi

    if not args.auto_roi:
        for option, value in (("--auto-roi-precision", args.auto_roi_precision), ("--noise-sigma", args.noise_sigma)):
            if value is not None:
                raise ValueError(f"{option} needs --auto-roi")
        return None
    precision = args.auto_roi_precision if args.auto_roi_precision is not None else DEFAULT_TARGET_PRECISION_PX
    return AutoRoi(noise_sigma_grey=args.noise_sigma, target_precision_px=precision)


# ------------------------------------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="workbench", description="Scheimpflug stereo-DIC virtual lab.")
    sub = p.add_subparsers(dest="command", required=True)

    render = sub.add_parser("render", help="render images with ground truth")
    rsub = render.add_subparsers(dest="what", required=True)
    cb = rsub.add_parser("checkerboard", help="random stereo views of the 12 x 9 checkerboard + truth.json")
    cb.add_argument("--rig", default="paper")
    cb.add_argument("--views", type=_views, default=10)
    cb.add_argument("--seed", type=_seed, default=0)
    cb.add_argument("--scale", type=_scale, default=1.0, help="shrink image size and K together (fast runs)")
    cb.add_argument("--spp", type=_positive_int, default=64, help="samples per pixel (Mitsuba renders)")
    cb.add_argument("--renderer", choices=("auto", "exact", "mitsuba"), default="auto",
                    help="auto: the exact box-filtered polygons wherever a view allows it (no Monte-Carlo noise), "
                         "Mitsuba elsewhere; exact: refuse a view it cannot make; mitsuba: Monte Carlo at --spp")
    cb.add_argument("--noise-grey", type=_non_negative_float, default=0.0, help="Gaussian read noise, grey levels")
    cb.add_argument("--bit-depth", type=int, choices=(8, 16), default=8)
    cb.add_argument("--format", choices=("png", "tiff"), default="png")
    cb.add_argument("--overwrite", action="store_true",
                    help="replace an earlier dataset in --out (deletes exactly the files its manifest.json lists)")
    cb.add_argument("--out", type=Path, required=True)

    rep = sub.add_parser("reproduce", help="run one of the paper's checks and write a report")
    repsub = rep.add_subparsers(dest="what", required=True)
    ag = repsub.add_parser("agreement", help="render <-> camera-model agreement at checkerboard corners")
    ag.add_argument("--rig", default="paper")
    ag.add_argument("--views", type=_views, default=2)
    ag.add_argument("--seed", type=_seed, default=0)
    ag.add_argument("--scale", type=_scale, default=1.0)
    ag.add_argument("--spp", type=_positive_int, default=256)
    ag.add_argument("--mc-target-grey", type=_positive_float, default=None,
                    help="render with the adaptive renderer at this Monte-Carlo noise (grey RMS) instead of --spp")
    ag.add_argument("--renderer", choices=("mitsuba", "exact"), default="mitsuba",
                    help="whose agreement with the camera model: Mitsuba's sensor plugin (default) or the exact "
                         "polygon renderer")
    ag.add_argument("--out", type=Path, required=True)
    rc = repsub.add_parser("calibration", help="the paper's calibration protocol on rendered views (Table 1, Fig 5)")
    rc.add_argument("--scale", type=_scale, default=1.0)
    rc.add_argument("--seed", type=_seed, default=0)
    rc.add_argument("--spp", type=_positive_int, default=64)
    rc.add_argument("--renderer", choices=("auto", "mitsuba"), default="auto",
                    help="board views: exact box-filtered polygons where possible (auto) or Monte Carlo (mitsuba)")
    rc.add_argument("--noise-grey", type=_non_negative_float, default=1.0)
    rc.add_argument("--calibration-views", type=_views, default=30)
    rc.add_argument("--validation-views", type=_views, default=20)
    rc.add_argument("--refine-corners", action="store_true", help="saddle-fit refinement of OpenCV's corners")
    rc.add_argument("--store", type=Path, default=None,
                    help="dataset store: renders kept by content hash and reused (default $WORKBENCH_STORE or "
                         "~/.cache/scheimpflug-dic-workbench/datasets)")
    rc.add_argument("--out", type=Path, required=True)
    rm = repsub.add_parser("rigid-motion", help="the paper's rigid-motion test (Fig 6) on rendered states, scored")
    rm.add_argument("--scale", type=_scale, default=1.0)
    rm.add_argument("--calib", default="rendered",
                    help="'rendered' (reproduced from rendered boards, default), 'true' (the true rig) or a file")
    rm.add_argument("--lens", choices=("thin", "pinhole"), default="pinhole",
                    help="pinhole (default) or thin lens at f/8 with the rig's tilted sensors (its focus plane misses the face)")
    rm.add_argument("--seed", type=_seed, default=0)
    rm.add_argument("--spp", type=_positive_int, default=64)
    rm.add_argument("--subset", type=_subset, default=65)
    rm.add_argument("--step", type=_positive_int, default=5)
    rm.add_argument("--store", type=Path, default=None,
                    help="dataset store: renders kept by content hash and reused (default $WORKBENCH_STORE or "
                         "~/.cache/scheimpflug-dic-workbench/datasets)")
    rm.add_argument("--out", type=Path, required=True)
    bd = repsub.add_parser("bending", help="the paper's three-point bending test (Figs 7-8): FE truth, strain, scored")
    bd.add_argument("--scale", type=_scale, default=1.0)
    bd.add_argument("--rig", choices=("scheimpflug", "paper"), default="scheimpflug",
                    help="scheimpflug (tilts from the Scheimpflug condition, default) or paper (Table 1 as printed)")
    bd.add_argument("--lens", choices=("thin", "pinhole"), default="thin")
    bd.add_argument("--calib", default="rendered",
                    help="'rendered' (reproduced from rendered boards, default), 'true' (the true rig) or a file")
    bd.add_argument("--seed", type=_seed, default=0)
    bd.add_argument("--spp", type=_positive_int, default=64)
    bd.add_argument("--noise-grey", type=_non_negative_float, default=1.0)
    bd.add_argument("--subset", type=_subset, default=65)
    bd.add_argument("--step", type=_positive_int, default=5)
    bd.add_argument("--window", type=_integer, default=15,
                    help="strain window (points per side, odd >= 3); 0 = per-triangle Cosserat strain, no window")
    bd.add_argument("--store", type=Path, default=None,
                    help="dataset store: renders kept by content hash and reused (default $WORKBENCH_STORE or "
                         "~/.cache/scheimpflug-dic-workbench/datasets)")
    bd.add_argument("--out", type=Path, required=True)
    f6 = repsub.add_parser("fig6-causes", help="which simulated error sources explain the paper's Fig 6 error growth "
                                                "(a study on Dask, resumable)")
    f6.add_argument("--study", type=Path, default=None, help="study file (default studies/fig6_causes.toml)")
    f6.add_argument("--scheduler", default=None, help="address of a running Dask scheduler; default a LocalCluster")
    f6.add_argument("--workers", type=_positive_int, default=2, help="LocalCluster process workers, default 2")
    f6.add_argument("--store", type=Path, default=None,
                    help="dataset store (renders by scenario hash); default $WORKBENCH_STORE or ~/.cache/...")
    f6.add_argument("--quiet", action="store_true", help="no progress bar")
    f6.add_argument("--out", type=Path, required=True)
    pp = repsub.add_parser("paper", help="the whole paper: calibration, rigid motion, bending, depth of field; one "
                                         "report (report.html, report.md) with every goal figure; resumable")
    pp.add_argument("--quick", action="store_true", help="quarter scale, same protocol (CI and the README)")
    pp.add_argument("--scale", type=_scale, default=None, help="image scale (default 1, or 0.25 with --quick)")
    pp.add_argument("--mc-target-grey", type=_positive_float, default=None,
                    help="Monte-Carlo noise target of the adaptive renders, grey RMS (default 0.3)")
    pp.add_argument("--seed", type=_seed, default=0)
    pp.add_argument("--strict", action="store_true", help="exit 1 when a goal figure is not met")
    pp.add_argument("--store", type=Path, default=None,
                    help="dataset store (renders by content hash); default $WORKBENCH_STORE or ~/.cache/...")
    pp.add_argument("--out", type=Path, required=True)
    da = repsub.add_parser("dic-accuracy", help="DIC bias vs sub-pixel shift, noise floor, shape functions")
    da.add_argument("--out", type=Path, required=True)
    from workbench.experiments.star import add_star_parser
    add_star_parser(repsub)
    dof = repsub.add_parser("depth-of-field", help="MIG of an oblique speckled plate: Scheimpflug vs untilted")
    dof.add_argument("--scale", type=_scale, default=1.0)
    dof.add_argument("--object-tilt-deg", type=_angle_deg, default=38.0)
    dof.add_argument("--f-number", type=_positive_float, default=4.0)
    dof.add_argument("--spp", type=_positive_int, default=64)
    dof.add_argument("--seed", type=_seed, default=0)
    dof.add_argument("--out", type=Path, required=True)
    cal = sub.add_parser("calibrate", help="stepwise Scheimpflug stereo calibration from checkerboard image pairs "
                                           "(or one camera's images with --camera)")
    cal.add_argument("--left", default=None, help="glob of left images, e.g. 'views/left_*.png' (sorted)")
    cal.add_argument("--right", default=None, help="glob of right images (sorted; paired with the left ones)")
    cal.add_argument("--camera", default=None, metavar="GLOB",
                     help="single-camera calibration of these images instead of a stereo pair (--left/--right); "
                          "writes a camera JSON (and an OpenCV YAML beside it)")
    cal.add_argument("--square-mm", type=_positive_float, default=5.0)
    cal.add_argument("--pattern", type=_pattern, default=(11, 8),
                     help="inner corners, COLSxROWS (default 11x8); with --target dots: the dots, COLSxROWS")
    cal.add_argument("--target", choices=("checkerboard", "charuco", "dots"), default="checkerboard",
                     help="calibration target: checkerboard (default), charuco (--squares, --marker-mm, --dictionary; "
                          "--square-mm the square) or dots (a symmetric dot grid: --pattern, --square-mm the pitch, "
                          "--dot-mm)")
    cal.add_argument("--squares", type=_pattern, default=None, help="ChArUco board squares, COLSxROWS")
    cal.add_argument("--marker-mm", type=_positive_float, default=None, help="ChArUco marker side, mm")
    cal.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco ArUco dictionary (default DICT_4X4_50)")
    cal.add_argument("--dot-mm", type=_positive_float, default=None, help="dot diameter, mm (--target dots)")
    cal.add_argument("--white-dots", action="store_true", help="light dots on a dark ground (--target dots)")
    cal.add_argument("--model", choices=("rmm", "opencv-tilt", "pinhole", "auto"), default="rmm",
                     help="camera model (default rmm, the paper's); auto: pinhole or rmm, whichever is the simplest "
                          "that held-out views support (and each candidate's tilt / sigma is printed)")
    cal.add_argument("--tilt-guess-deg", type=_tilt_pair, default=(0.0, 0.0),
                     help="datasheet tilt (alpha,beta) of the left camera for step 1")
    cal.add_argument("--tilt-guess-right-deg", type=_tilt_pair, default=None,
                     help="right camera's (alpha,beta); default mirrors the left one: (alpha,-beta)")
    cal.add_argument("--no-joint", action="store_true", help="skip the final joint refinement")
    cal.add_argument("--refine-corners", action="store_true", help="saddle-fit refinement of OpenCV's corners")
    from measurement.calibration.stepwise import LENS_ALIASES, LENSES
    cal.add_argument("--lens", choices=tuple(LENS_ALIASES) + LENSES + ("auto",), default="brown4",
                     help="lens distortion: k1k2p1p2 = brown4 (the paper, default), k1k2k3p1p2 = brown5 (also the r^6 "
                          "term k3; then both are fitted and the output says whether k3 is worth it), full (also the "
                          "thin prism s1-s4 and the skew), or auto (the simplest the held-out views support)")
    cal.add_argument("--folds", type=_positive_int, default=8,
                     help="most folds of the held-out-view test of --model/--lens auto (default 8)")
    cal.add_argument("--out", type=Path, required=True, help="calibration JSON (a .yaml OpenCV export is written beside)")

    from measurement.stereo_dic import MAX_MEDIAN_RESIDUAL_PX, MIN_MEASURED_FRACTION

    st = sub.add_parser("stereo", help="stereo-DIC of an image sequence with a calibration file (real or rendered)")
    st.add_argument("--calib", type=Path, required=True, help="calibration JSON (workbench calibrate) or OpenCV YAML")
    st.add_argument("--left-ref", type=Path, required=True, help="left reference image")
    st.add_argument("--right-ref", type=Path, required=True, help="right reference image")
    st.add_argument("--left", required=True, help="glob of left deformed images (sorted; paired with --right)")
    st.add_argument("--right", required=True, help="glob of right deformed images")
    st.add_argument("--roi", type=_roi, default=None, help="rectangle of points on the left reference X0,Y0,X1,Y1")
    st.add_argument("--mask", type=Path, default=None,
                    help="image (the left reference's size) whose non-zero pixels may hold points of interest")
    st.add_argument("--subset", type=_subset, default=65, help="subset size (odd, px), default 65")
    st.add_argument("--step", type=_positive_int, default=5, help="grid step (px), default 5")
    st.add_argument("--order", type=int, choices=(1, 2), default=2)
    st.add_argument("--min-zncc", type=_zncc, default=0.8)
    st.add_argument("--max-residual-px", type=_positive_float, default=MAX_MEDIAN_RESIDUAL_PX,
                    help="refuse the reference or a state whose median triangulation residual is above this "
                         f"(px), default {MAX_MEDIAN_RESIDUAL_PX:g}")
    st.add_argument("--min-measured-fraction", type=_fraction, default=MIN_MEASURED_FRACTION,
                    help="refuse the reference (of its points) or a state (of the reference's points) measuring less "
                         f"than this fraction, default {MIN_MEASURED_FRACTION:g}")
    st.add_argument("--auto-roi", action="store_true",
                    help="automatic ROI: points whose left-reference subset lacks texture are flagged low_texture "
                         "and not matched; matches that disagree with their neighbours are flagged inconsistent")
    _auto_roi_options(st)
    st.add_argument("--overwrite", action="store_true",
                    help="replace earlier results in --out (deletes exactly the files its manifest.json lists)")
    st.add_argument("--out", type=Path, required=True,
                    help="output folder (CSV + VTK per state, summary.csv, manifest.json); exit 1 if a state failed")

    dic = sub.add_parser("dic", help="2-D subset DIC between a reference and a deformed image (any 8/16-bit grey files)")
    dic.add_argument("reference", type=Path, help="reference image file")
    dic.add_argument("deformed", type=Path, help="deformed image file")
    dic.add_argument("--roi", type=_roi, default=None, help="rectangle of points of interest X0,Y0,X1,Y1 (px)")
    dic.add_argument("--mask", type=Path, default=None, help="image whose non-zero pixels may hold points of interest")
    dic.add_argument("--subset", type=_subset, default=33, help="subset size 2M+1 (odd, px), default 33")
    dic.add_argument("--step", type=_positive_int, default=8, help="grid step (px), default 8")
    dic.add_argument("--order", type=int, choices=(1, 2), default=1, help="shape function order, default 1")
    dic.add_argument("--interp", choices=("biquintic", "bicubic"), default="biquintic")
    dic.add_argument("--seed-point", type=_pair, action="append", default=None,
                     help="preferred seed X,Y (px); may be repeated")
    dic.add_argument("--seed-guess", type=_pair, default=(0.0, 0.0),
                     help="displacement U,V (px) at which the seed search is centred, default 0,0")
    dic.add_argument("--search-radius", type=_positive_int, default=32, help="seed search half-width (px)")
    dic.add_argument("--min-zncc", type=_zncc, default=0.8, help="points below this ZNCC are rejected")
    dic.add_argument("--tolerance", type=_positive_float, default=1e-3,
                     help="IC-GN convergence threshold (px at the subset edge)")
    dic.add_argument("--lowpass-sigma", type=_non_negative_float, default=0.0,
                     help="Gaussian pre-filter sigma (px), default off")
    dic.add_argument("--threads", type=_positive_int, default=None, help="worker threads (default: all cores)")
    dic.add_argument("--auto-roi", action="store_true",
                     help="automatic ROI: points whose reference subset lacks texture are flagged low_texture and not "
                          "correlated; converged points that disagree with their neighbours are flagged inconsistent")
    _auto_roi_options(dic)
    dic.add_argument("--out", type=Path, required=True, help="CSV of the points (x,y,u,v,zncc,iterations,status,...)")

    for name, text in (("sweep", "run a study file (axes x repeats) on Dask: results.nc, results.csv, report.html"),
                       ("budget", "error budget: each error source of a study file alone, then all together")):
        sw = sub.add_parser(name, help=text)
        sw.add_argument("study", type=Path, help="study file (.toml or .json)")
        sw.add_argument("--scheduler", default=None,
                        help="address of a running Dask scheduler (tcp://host:8786); default: a LocalCluster")
        sw.add_argument("--workers", type=_positive_int, default=2, help="LocalCluster process workers, default 2")
        sw.add_argument("--store", type=Path, default=None,
                        help="dataset store (renders by scenario hash); default $WORKBENCH_STORE or ~/.cache/...")
        sw.add_argument("--quiet", action="store_true", help="no progress bar")
        sw.add_argument("--no-points", dest="points", action="store_false",
                        help="no per-point file per case (cases/<hash>.points.csv: u, v, truth, status of every "
                             "point, for experiments that have one); default: written")
        sw.add_argument("--out", type=Path, required=True,
                        help="output folder (cases/<hash>.json, results.nc, results.csv, report.html); rerun the "
                             "same command to resume")
        if name == "budget":
            sw.add_argument("--metric", required=True, help="the metric whose budget is drawn")
            sw.add_argument("--at", default=None,
                            help="for a metric over a dimension (e.g. stage_mm), the value to take: DIM=VALUE")
    from workbench.tool_cli import add_parsers as _tool_parsers
    _tool_parsers(sub, _positive_int)
    from workbench.tool_cli import add_gate_parser as _gate_parser
    _gate_parser(sub)
    sub.add_parser("parameters", help="list every scenario.* and instrument.* parameter with its default and doc")
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
    conv.add_argument("--image-size", type=_pair, default=None, metavar="W,H",
                      help="image size of a source that holds none (MatchID .caldat), px")
    conv.add_argument("--frame-rotation", action="store_true",
                      help="let a format without the paper's tilt absorb it in a rotation of the camera frames")
    return p


# ------------------------------------------------------------------------------------------------------------
def _rig_option(calib: str) -> None:
    """``--calib rendered|true|FILE``: a file must exist (checked before any rendering)."""
    if calib not in ("rendered", "true"):
        path = Path(calib)
        if path.is_dir():
            raise ValueError(f"--calib {calib} is a directory, not a calibration file")
        if not path.is_file():
            raise ValueError(f"calibration file not found: {calib} (--calib takes 'true', 'rendered' or a "
                             "calibration file)")


def _reproduce_rigid_motion(args) -> int:
    from workbench.experiments.rigid_motion import reproduce_rigid_motion

    _rig_option(args.calib)
    _output_folder(args.out)
    m = reproduce_rigid_motion(args.out, scale=args.scale, calib=args.calib, lens=args.lens, seed=args.seed,
                               spp=args.spp, subset_size=args.subset, step=args.step, store=args.store)
    e = m["reference_3d_error_um"]
    print(f"{m['calibration']}: reference 3D error {e['aligned_rms']:.3f} um aligned ({e['unaligned_rms']:.1f} um "
          f"unaligned), {m['points']} points")
    for r in m["states"]:
        if "error" in r:
            print(f"  {r['imposed_mm']:5.1f} mm: skipped ({r['error']})")
            continue
        paper = "" if r["paper_mean_um"] is None else f"; paper {r['paper_mean_um']:.1f} / {r['paper_std_um']:.1f} um"
        print(f"  {r['imposed_mm']:5.1f} mm: mean error {r['mean_error_um']:+.3f} um, std {r['std_um']:.3f} um "
              f"({r['points']} points){paper}")
    print(f"wrote {args.out / 'report.md'}")
    return 0 if any("error" not in r for r in m["states"]) else 1


def _reproduce_bending(args) -> int:
    from workbench.experiments.bending import reproduce_bending

    if args.window != 0 and (args.window < 3 or args.window % 2 == 0):
        raise ValueError(f"--window must be 0 (per-triangle strain) or an odd number >= 3, got {args.window}")
    _rig_option(args.calib)
    _output_folder(args.out)
    m = reproduce_bending(args.out, scale=args.scale, rig_name=args.rig, lens=args.lens, calib=args.calib,
                          seed=args.seed, spp=args.spp, noise_grey=args.noise_grey, subset_size=args.subset,
                          step=args.step, window=args.window or None, store=args.store)
    print(f"{m['calibration']}: {m['points']} points, VSG {m['vsg_px']} px")
    for r in m["states"]:
        if "error" in r:
            print(f"  {r['load_N']:6.0f} N: skipped ({r['error']})")
            continue
        print(f"  {r['load_N']:6.0f} N: U/V/W RMSE " + " / ".join(f"{v:.3f}" for v in r["U_rmse_um"])
              + f" um; strain RMSE {r['strain_magnitude_rmse_vs_filtered_ue']:.1f} ue vs windowed truth "
              f"({r['strain_rmse_vs_filtered_percent_of_peak']:.1f} % of the {r['peak_truth_strain_ue']:.0f} ue peak)")
    print(f"wrote {args.out / 'report.md'}")
    measured = [r for r in m["states"] if "error" not in r]
    return 0 if measured else 1


def _reproduce_paper(args) -> int:
    from workbench.experiments.paper import PaperSettings, reproduce_paper

    settings = PaperSettings.for_mode(args.quick, args.scale, args.mc_target_grey, args.seed)
    summary = reproduce_paper(args.out, settings, store=args.store)
    failed = [g for g in summary["goals"] if g["met"] is False]
    return 1 if (args.strict and failed) else 0


def _reproduce_dic_accuracy(args) -> int:
    from workbench.experiments.dic_accuracy import reproduce_dic_accuracy

    _output_folder(args.out)
    metrics = reproduce_dic_accuracy(args.out)
    for curve in metrics["bias"]:
        print(f"bias {curve['label']}: max {curve['max_abs_px']:.5f} px")
    print(f"noise ratio std(u)/theory: {metrics['noise']['all']['ratio']:.3f}; wrote {args.out / 'report.md'}")
    return 0


def _load_rig(path: Path, image_size_px: tuple[int, int] | None = None):
    """Any calibration file the instrument reads (JSON, OpenCV YAML/XML, DICe, VIC-3D, MatchID: detected from the
    content); ``image_size_px`` for a format that holds none (MatchID)."""
    from measurement.calibration.formats import load_any_calibration

    if path.is_dir():
        raise ValueError(f"--calib {path} is a directory, not a calibration file")
    if not path.is_file():
        raise ValueError(f"calibration file not found: {path}")
    return load_any_calibration(path, image_size_px=image_size_px)


def _check_against_calibration(image: np.ndarray, camera, what: str) -> None:
    if image.shape != (camera.height, camera.width):
        raise ValueError(f"{what} is {_size(image)} but the calibration is for {camera.width} x {camera.height} px")


def _stereo(args) -> int:
    from measurement.dic import DICSettings
    from measurement.stereo_dic import StereoMatchError, StereoQualityError, measure_state, reference_shape
    from measurement.stereo_io import write_state_csv, write_state_summary, write_state_vtk
    from workbench.manifest import complete_folder, prepare_folder

    # Everything is checked before the first match and the first write.
    _input_file(args.left_ref, "--left-ref")
    left_ref = _read_image(args.left_ref, "--left-ref")     # its size is what a MatchID file lacks
    rig = _load_rig(args.calib, (left_ref.shape[1], left_ref.shape[0]))
    _input_file(args.right_ref, "--right-ref")
    if _resolved(args.left_ref) == _resolved(args.right_ref):
        raise ValueError(f"--left-ref and --right-ref are the same file ({args.left_ref})")
    left_files, right_files = _paired_globs(args.left, args.right)
    _output_folder(args.out)
    right_ref = _read_image(args.right_ref, "--right-ref")
    _check_against_calibration(left_ref, rig.left, f"--left-ref {args.left_ref}")
    _check_against_calibration(right_ref, rig.right, f"--right-ref {args.right_ref}")
    for fl, fr in zip(left_files, right_files):
        _check_against_calibration(_read_image(fl, "left image"), rig.left, f"left image {fl}")
        _check_against_calibration(_read_image(fr, "right image"), rig.right, f"right image {fr}")
    mask = None
    if args.mask is not None:
        mask_image = _read_image(args.mask, "--mask")
        if mask_image.shape[:2] != left_ref.shape[:2]:
            raise ValueError(f"--mask {args.mask} is {_size(mask_image)} but the left reference is {_size(left_ref)}")
        mask = mask_image != 0 if mask_image.ndim == 2 else np.any(mask_image != 0, axis=-1)
    _poi_grid(left_ref, args, mask, what="left reference image")
    auto_roi = _auto_roi(args)
    settings = DICSettings(subset_size=args.subset, step=args.step, order=args.order, min_zncc=args.min_zncc)
    names = [f"state_{k:03d}" for k in range(len(left_files))]
    planned = ["reference.csv", "reference.vtk", "summary.csv"] + [f"{n}.{e}" for n in names for e in ("csv", "vtk")]
    prepare_folder(args.out, "stereo", planned, overwrite=args.overwrite, dry_run=True)
    thresholds = dict(max_median_residual_px=args.max_residual_px, min_measured_fraction=args.min_measured_fraction)
    hint = (f" (calibration {args.calib}; thresholds: --max-residual-px {args.max_residual_px:g}, "
            f"--min-measured-fraction {args.min_measured_fraction:g})")

    try:
        shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, left_ref,
                                right_ref, settings, roi=args.roi, mask=mask, auto_roi=auto_roi, **thresholds)
    except StereoQualityError as err:
        raise ValueError(f"{err}{hint}") from None
    prepare_folder(args.out, "stereo", planned, overwrite=args.overwrite)
    written = [write_state_csv(args.out / "reference.csv", shape).name,
               write_state_vtk(args.out / "reference.vtk", shape).name]
    q = shape.quality
    print(f"reference: {q.measured}/{shape.x.size} points triangulated, median residual {q.median_residual_px:.4f} px, "
          f"95th percentile {q.p95_residual_px:.4f} px")
    if shape.auto_roi_report is not None:
        print(f"reference {shape.auto_roi_report.summary()}")
    rows = [{"state": "reference", "left": str(args.left_ref), "right": str(args.right_ref), "quality": q}]
    from tqdm import tqdm

    from measurement.image_io import read_grey
    skipped = []
    for k, (fl, fr) in enumerate(tqdm(list(zip(left_files, right_files)), desc="stereo states")):
        what = f"state {k} ({fl}, {fr})"
        try:
            state = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape,
                                  left_ref, read_grey(fl), read_grey(fr), settings, name=what, **thresholds)
        except StereoMatchError as err:
            message = f"{err}{hint}" if isinstance(err, StereoQualityError) else f"{what}: {err}"
            tqdm.write(f"workbench stereo: state {k} skipped: {message}", file=sys.stderr)
            skipped.append(k)
            rows.append({"state": names[k], "left": fl, "right": fr, "quality": getattr(err, "quality", None),
                         "error": message})
            continue
        written += [write_state_csv(args.out / f"{names[k]}.csv", shape, state).name,
                    write_state_vtk(args.out / f"{names[k]}.vtk", shape, state).name]
        q = state.quality
        rows.append({"state": names[k], "left": fl, "right": fr, "quality": q,
                     "mean_D_mm": float(np.nanmean(state.D_mm[state.valid]))})
        tqdm.write(f"state {k} ({Path(fl).name}, {Path(fr).name}): {q.measured}/{q.points} points, median residual "
                   f"{q.median_residual_px:.4f} px, 95th percentile {q.p95_residual_px:.4f} px, mean D "
                   f"{rows[-1]['mean_D_mm']:.4f} mm")
        if state.auto_roi_report is not None:
            tqdm.write(f"state {k} {state.auto_roi_report.summary()}")
    written.append(write_state_summary(args.out / "summary.csv", rows).name)
    complete_folder(args.out, "stereo", written,
                    {"calib": str(args.calib), "left_ref": str(args.left_ref), "right_ref": str(args.right_ref),
                     "left": args.left, "right": args.right, "roi": args.roi,
                     "mask": None if args.mask is None else str(args.mask), "subset": args.subset,
                     "step": args.step, "order": args.order, "min_zncc": args.min_zncc, **thresholds,
                     "auto_roi": None if auto_roi is None else vars(auto_roi) | {"noise_sigma_used_grey":
                                                                                  shape.noise_sigma_grey},
                     "skipped_states": skipped})
    print(f"wrote {args.out} ({len(left_files) - len(skipped)} of {len(left_files)} states; summary.csv)")
    if skipped:
        print(f"workbench stereo: error: {len(skipped)} of {len(left_files)} states could not be measured (states "
              f"{', '.join(map(str, skipped))}; see the messages above and {args.out / 'summary.csv'})",
              file=sys.stderr)
        return 1
    return 0


def _dic(args) -> int:
    import numba

    from measurement.dic import DICSettings, Status, correlate

    reference = _read_image(args.reference, "reference image")
    deformed = _read_image(args.deformed, "deformed image")
    if reference.shape != deformed.shape:
        raise ValueError(f"{args.reference} is {reference.shape[1]} x {reference.shape[0]} px but {args.deformed} is "
                         f"{deformed.shape[1]} x {deformed.shape[0]} px: the images must have the same size")
    _output_file(args.out)
    mask = None
    if args.mask is not None:
        mask_image = _read_image(args.mask, "--mask")
        if mask_image.shape != reference.shape:
            raise ValueError(f"--mask {args.mask} is {_size(mask_image)} but the images are {_size(reference)}")
        mask = mask_image != 0
    h, w = reference.shape
    for x, y in args.seed_point or ():
        if not (0 <= x <= w - 1 and 0 <= y <= h - 1):
            raise ValueError(f"--seed-point {x:g},{y:g} is outside the {_size(reference)} image "
                             f"(0 <= X <= {w - 1}, 0 <= Y <= {h - 1})")
    u, v = args.seed_guess
    if abs(u) >= w or abs(v) >= h:
        raise ValueError(f"--seed-guess {u:g},{v:g} moves the seed search outside the {_size(reference)} image")
    grid = _poi_grid(reference, args, mask)
    auto_roi = _auto_roi(args)
    settings = DICSettings(subset_size=args.subset, step=args.step, order=args.order, interpolation=args.interp,
                           search_radius_px=args.search_radius, min_zncc=args.min_zncc,
                           tolerance_px=args.tolerance, lowpass_sigma_px=args.lowpass_sigma)
    if args.threads:
        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    report = None
    try:
        if auto_roi is None:
            result = correlate(reference, deformed, settings, grid=grid, seed_points_xy=args.seed_point,
                               seed_guess_px=args.seed_guess)
        else:
            from measurement.dic.roi import correlate_auto_roi

            result, report = correlate_auto_roi(reference, deformed, settings, grid=grid, auto_roi=auto_roi,
                                                seed_points_xy=args.seed_point, seed_guess_px=args.seed_guess)
    except ValueError as err:
        if str(err).startswith("seed point"):
            raise ValueError(f"--seed-point: {err}") from None
        raise
    result.to_csv(args.out)
    ok = result.converged
    counts = ", ".join(f"{name.lower()} {n}" for name, n in result.status_counts().items())
    print(f"{result.x.size} points ({counts}) in {result.timings_s['total']:.2f} s; wrote {args.out}")
    if report is not None:
        print(report.summary())
    if ok.any():
        print(f"  u {np.nanmin(result.u):.4f} .. {np.nanmax(result.u):.4f} px, v {np.nanmin(result.v):.4f} .. "
              f"{np.nanmax(result.v):.4f} px, median ZNCC {np.median(result.zncc[ok]):.4f}, "
              f"mean iterations {result.iterations[ok].mean():.2f}")
    else:
        print(f"workbench dic: error: no point converged (statuses: "
              f"{', '.join(Status(s).name for s in np.unique(result.status))})", file=sys.stderr)
        return 1
    return 0


def _calibration_texts(cal, pairs, extra: dict | None = None) -> tuple[str, str]:
    """The calibration JSON and its OpenCV YAML export as texts, built before either file is written."""
    import tempfile

    from measurement.calibration.io import export_opencv_yaml, save_calibration

    with tempfile.TemporaryDirectory(prefix="workbench-calibrate-") as tmp:
        json_path, yaml_path = Path(tmp) / "calibration.json", Path(tmp) / "calibration.yaml"
        try:
            save_calibration(cal, json_path, extra={"images": {"left": pairs.left_files, "right": pairs.right_files,
                                                               "dropped": pairs.dropped}, **(extra or {})})
            export_opencv_yaml(cal, yaml_path)
            return json_path.read_text(encoding="utf-8"), yaml_path.read_text(encoding="utf-8")
        except OSError as err:
            raise OSError(f"cannot build the calibration files in {tmp}: {err.strerror or err}") from None


def _auto_candidates(model: str, lens: str) -> list[tuple[str, str]]:
    """The (model, lens) candidates of ``--model auto`` / ``--lens auto`` (the other option fixed if not auto)."""
    from measurement.calibration.stepwise import LENSES, canonical_lens

    models = ("pinhole", "rmm") if model == "auto" else (model,)
    lenses = LENSES if lens == "auto" else (canonical_lens(lens),)
    return [(m, ln) for m in models for ln in lenses]


def _parameter_names(lens: str) -> tuple[str, ...]:
    from measurement.calibration.stepwise import LENS_TERMS

    terms = LENS_TERMS[lens]
    return (("fx", "fy") + (("skew",) if "skew" in terms else ()) + ("cx", "cy", "alpha_deg", "beta_deg", "k1", "k2")
            + (("k3",) if "k3" in terms else ()) + ("p1", "p2") + tuple(t for t in terms if t.startswith("s")))


def _calibration_target(args):
    """The target spec of ``calibrate``'s options (None: the checkerboard of --pattern), checked."""
    from measurement.calibration.targets import CharucoSpec, DotGridSpec

    if args.target != "charuco" and (args.squares or args.marker_mm):
        raise ValueError("--squares and --marker-mm describe a ChArUco board: add --target charuco")
    if args.target != "dots" and (args.dot_mm or args.white_dots):
        raise ValueError("--dot-mm and --white-dots describe a dot grid: add --target dots")
    if args.target != "checkerboard" and args.refine_corners:
        raise ValueError("--refine-corners refines checkerboard corners; it does not apply to --target "
                         f"{args.target}")
    if args.target == "charuco":
        if args.squares is None or args.marker_mm is None:
            raise ValueError("--target charuco needs --squares COLSxROWS and --marker-mm (and --square-mm)")
        return CharucoSpec(squares=args.squares, square_mm=args.square_mm, marker_mm=args.marker_mm,
                           dictionary=args.dictionary)
    if args.target == "dots":
        if args.dot_mm is None:
            raise ValueError("--target dots needs --dot-mm (and --pattern COLSxROWS dots, --square-mm the pitch)")
        return DotGridSpec(pattern_size=args.pattern, pitch_mm=args.square_mm, diameter_mm=args.dot_mm,
                           dark_dots=not args.white_dots)
    return None


def _calibration_check(args) -> tuple[str, str]:
    """Options of ``calibrate`` checked before any board is detected; returns the (model, lens) as asked."""
    if args.camera is not None and (args.left is not None or args.right is not None):
        raise ValueError("--camera calibrates one camera: give its images with --camera only, not --left/--right")
    if args.camera is None and (args.left is None or args.right is None):
        raise ValueError("give --left and --right (a stereo pair) or --camera (one camera)")
    if args.out.suffix.lower() in (".yaml", ".yml", ".xml"):
        raise ValueError(f"--out {args.out} names the YAML export; give the calibration JSON (e.g. "
                         f"{args.out.with_suffix('.json')}): the .yaml is written beside it")
    _calibration_target(args)
    return args.model, args.lens


def _print_significance(cal, model: str | None = None) -> None:
    """Each optional term's value / sigma on stdout; the terms the data do not determine as warnings on stderr."""
    from measurement.calibration.model_selection import significance_lines

    lines, warns = significance_lines(cal, model=model)
    if lines:
        print("  terms beyond the pinhole camera with k1 k2 p1 p2 (value ± sigma, z = |value| / sigma):")
        print("\n".join(lines))
    for w in warns:
        print(f"warning: {w}", file=sys.stderr)


def _calibrate_one_camera(args) -> int:
    """``workbench calibrate --camera GLOB``: steps 1-4 (and the final refinement) of one camera."""
    import warnings

    from measurement.calibration.images import MIN_VIEWS, detect_views, target_points_mm
    from measurement.calibration.io import opencv_camera_yaml_text, save_camera_calibration
    from measurement.calibration.model_selection import select_camera_model, term_significance
    from measurement.calibration.stepwise import calibrate_camera
    from workbench.manifest import write_texts_together

    files = _glob_files(args.camera, "--camera")
    if len(files) < MIN_VIEWS:
        raise ValueError(f"calibration needs at least {MIN_VIEWS} images; --camera {args.camera!r} matches {len(files)}")
    yaml_out = args.out.with_suffix(".yaml")
    _output_file(args.out)
    _output_file(yaml_out, "the YAML export beside --out")
    target = _calibration_target(args)
    views = detect_views(files, args.pattern, refine=args.refine_corners, target=target)
    board = target_points_mm(target, args.pattern, args.square_mm)
    candidates = _auto_candidates(args.model, args.lens)
    rows = []
    if len(candidates) > 1:
        (model, lens), rows = select_camera_model(views.points, board, views.image_size, candidates=candidates,
                                                  folds=args.folds, tilt_guess_deg=args.tilt_guess_deg)
        print(f"  model selection over {len(rows)} candidates ({min(args.folds, len(views.files))}-fold held-out "
              "views; simplest within one standard error of the best):")
        for r in rows:
            print(f"    {r['model']:<8} {r['lens']:<7} held-out MSE {r['held_out_mse_px2']:.5f} ± {r['se_px2']:.5f} "
                  f"px²{'  <- chosen' if r['chosen'] else ''}")
    else:
        model, lens = candidates[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cal = calibrate_camera(views.points, board, views.image_size, model=model, tilt_guess_deg=args.tilt_guess_deg,
                               lens=lens)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    extra = {"images": {"files": views.files, "dropped": views.dropped},
             "significance": term_significance(cal, model)["camera"],
             **({"model_selection": {"rule": "simplest candidate within one standard error of the lowest held-out "
                                              "MSE", "candidates": rows}} if rows else {})}
    import tempfile

    with tempfile.TemporaryDirectory(prefix="workbench-calibrate-") as tmp:     # validated text, then both files
        json_path = Path(tmp) / "camera.json"
        save_camera_calibration(cal, json_path, model=model, extra=extra)
        json_text = json_path.read_text(encoding="utf-8")
    write_texts_together({args.out: json_text, yaml_out: opencv_camera_yaml_text(cal, yaml_out)})
    print(f"calibrated one camera ({model}, lens {lens}) from {len(views.files)} images ({len(views.dropped)} dropped)")
    params = ", ".join(f"{n}={getattr(cal.camera, n):.5g}±{cal.sigma.get(n, 0.0):.2g}" for n in _parameter_names(lens)
                       if not (model == "pinhole" and n in ("alpha_deg", "beta_deg")))
    print(f"  reprojection RMS {cal.rms_px:.4f} px; {params}")
    _print_significance(cal, model)
    print(f"  wrote {args.out} and {yaml_out}")
    return 0


def _calibrate(args) -> int:
    from measurement.calibration.images import MIN_VIEWS, calibrate_from_files
    from workbench.manifest import write_texts_together

    # Options and inputs are checked before any board is detected.
    model, lens = _calibration_check(args)
    if args.camera is not None:
        return _calibrate_one_camera(args)
    _output_file(args.out)
    yaml_out = args.out.with_suffix(".yaml")
    _output_file(yaml_out, "the YAML export beside --out")
    left, right = _paired_globs(args.left, args.right)
    if len(left) < MIN_VIEWS:
        raise ValueError(f"calibration needs at least {MIN_VIEWS} stereo pairs; --left {args.left!r} matches "
                         f"{len(left)}")
    first = None
    for f in left + right:
        image = _read_image(f, "image")
        if first is None:
            first = (image.shape, f)
        elif image.shape != first[0]:
            raise ValueError(f"image {f} is {_size(image)} but {first[1]} is {first[0][1]} x {first[0][0]} px: all "
                             "images must have one size")
    guess_r = args.tilt_guess_right_deg or (args.tilt_guess_deg[0], -args.tilt_guess_deg[1])
    from measurement.calibration.images import target_points_mm
    from measurement.calibration.stepwise import calibrate_stereo, canonical_lens

    target = _calibration_target(args)
    board = target_points_mm(target, args.pattern, args.square_mm)
    settings = dict(tilt_guess_left_deg=args.tilt_guess_deg, tilt_guess_right_deg=guess_r, joint=not args.no_joint)
    comparison = selection = None
    extra = {}
    if "auto" in (model, lens):
        from measurement.calibration import images
        from measurement.calibration.model_selection import select_model

        pairs = images.detect_pairs(left, right, args.pattern, refine=args.refine_corners, target=target)
        selection = select_model(pairs.points_left, pairs.points_right, board, pairs.image_size,
                                 candidates=_auto_candidates(model, lens), folds=args.folds,
                                 progress=lambda text: print(f"  fitting {text}", flush=True), **settings)
        cal = selection.calibration
        extra["model_selection"] = selection.to_dict()
    else:
        lens = canonical_lens(lens)
        cal, pairs = calibrate_from_files(left, right, square_mm=args.square_mm, pattern_size=args.pattern,
                                          model=model, refine_corners=args.refine_corners, target=target,
                                          lens="brown4" if lens == "brown5" else lens, **settings)
        if lens == "brown5":
            # the four-term fit above is the reference of the comparison; the five-term one is what is written
            from measurement.calibration.stepwise import compare_lens_models

            brown5 = calibrate_stereo(pairs.points_left, pairs.points_right, board, pairs.image_size, lens="brown5",
                                      model=model, **settings)
            comparison = compare_lens_models(pairs.points_left, pairs.points_right, board, pairs.image_size,
                                             brown4=cal, brown5=brown5, model=model, **settings)
            cal = brown5
            extra["lens_comparison"] = comparison
    from measurement.calibration.model_selection import term_significance

    extra["significance"] = {"rule": "z = |value| / sigma of each term beyond the pinhole camera with k1 k2 p1 p2; "
                                     "z < 3: not determined by the data", **term_significance(cal)}
    json_text, yaml_text = _calibration_texts(cal, pairs, extra)
    write_texts_together({args.out: json_text, yaml_out: yaml_text})       # both files or neither
    lens_text = "" if cal.lens == "brown4" else f" (lens {cal.lens})"
    print(f"calibrated {cal.model}{lens_text} from {len(pairs.left_files)} stereo views ({len(pairs.dropped)} images "
          f"dropped)")
    for side in ("left", "right"):
        c = getattr(cal, side)
        params = ", ".join(f"{n}={getattr(c.camera, n):.5g}±{c.sigma.get(n, 0.0):.2g}" for n in _parameter_names(cal.lens))
        print(f"  {side}: reprojection RMS {c.rms_px:.4f} px; {params}")
    if selection is not None:
        print("\n".join(selection.lines()))
    if comparison is not None:
        from measurement.calibration.stepwise import lens_comparison_lines
        print("\n".join(lens_comparison_lines(comparison)))
    _print_significance(cal)
    print(f"  stereo T = {np.round(cal.T_right_from_left_mm, 4).tolist()} mm; wrote {args.out} and {yaml_out}")
    return 0


def _reproduce_calibration(args) -> int:
    from workbench.experiments.calibration import reproduce_calibration

    _output_folder(args.out)
    m = reproduce_calibration(args.out, scale=args.scale, seed=args.seed, spp=args.spp, noise_grey=args.noise_grey,
                              n_calibration=args.calibration_views, n_validation=args.validation_views,
                              refine_corners=args.refine_corners, store=args.store, renderer=args.renderer)
    for model, r in m["models"].items():
        v, pf = r["validation_exact"], r["validation_plane_fit"]
        print(f"{model:8s}: reprojection RMS {r['reprojection_rms_px']['left']:.4f} / "
              f"{r['reprojection_rms_px']['right']:.4f} px; 3D RMS {v['rms_3d_aligned_um']:.3f} um aligned "
              f"({v['rms_3d_unaligned_um']:.1f} um unaligned); projection {v['projection_rms_px']:.4f} px; plane fit "
              f"RMSE {pf['rmse_um']:.2f} um, max {pf['max_abs_um']:.2f} um; calibration {r['calibration_s']} s")
    print(f"report: {args.out / 'report.md'}")
    return 0


def _render_checkerboard(args) -> int:
    from scenes.noise import SensorNoise
    from workbench.experiments.checkerboard_views import write_checkerboard_dataset
    from workbench.rigs import get_rig

    _output_folder(args.out)
    rig = get_rig(args.rig, args.scale)
    noise = SensorNoise(read_noise_grey=args.noise_grey, bit_depth=args.bit_depth)
    truth = write_checkerboard_dataset(rig, args.out, args.views, args.seed, spp=args.spp, noise=noise,
                                       image_format=args.format, overwrite=args.overwrite, renderer=args.renderer)
    made = ", ".join(f"{n} by {name}" for name, n in truth["render"]["renderers"].items())
    print(f"wrote {len(truth['images'])} images ({made}), truth.json and manifest.json to {args.out}")
    return 0


def _reproduce_agreement(args) -> int:
    from workbench.experiments.render_agreement import measure_agreement, summary_lines, write_agreement_report
    from workbench.rigs import get_rig

    _output_folder(args.out)
    rig = get_rig(args.rig, args.scale)
    spp = args.spp if args.mc_target_grey is None else f"adaptive:{args.mc_target_grey:g}"
    summary = measure_agreement(rig, n_views=args.views, seed=args.seed, spp=spp, renderer=args.renderer)
    write_agreement_report(summary, args.out)
    print("\n".join(summary_lines(summary)))
    print(f"report: {args.out / 'report.md'}")
    return 0 if all(e["meets_goal"] for e in summary["cameras"].values()) else 1


def _reproduce_depth_of_field(args) -> int:
    from workbench.experiments.depth_of_field import reproduce_depth_of_field

    _output_folder(args.out)
    m = reproduce_depth_of_field(args.out, scale=args.scale, object_tilt_deg=args.object_tilt_deg,
                                 f_number=args.f_number, spp=args.spp, seed=args.seed)
    for name, c in m["cameras"].items():
        print(f"{name:13s}: MIG {c['mig']:.2f}, blur median {c['blur_px']['median']:.2f} px (max {c['blur_px']['max']:.2f}), "
              f"noise floor {c['noise_floor_px']['u']:.4f} / {c['noise_floor_px']['v']:.4f} px, "
              f"displacement error RMS {c['displacement_error_px']['rms']:.4f} px")
    print(f"MIG ratio {m['mig_ratio']:.2f} (paper {m['paper_mig_scheimpflug'] / m['paper_mig_conventional']:.2f}); "
          f"wrote {args.out / 'report.md'}")
    return 0


def _sweep(args) -> int:
    from workbench.sweep_cli import sweep_command
    return sweep_command(args)


def _fig6_causes(args) -> int:
    from workbench.sweep_cli import fig6_causes_command
    return fig6_causes_command(args)


def _budget(args) -> int:
    from workbench.sweep_cli import budget_command
    return budget_command(args)


_SUFFIX_FORMAT = {".json": "json", ".yaml": "opencv", ".yml": "opencv", ".xml": "opencv", ".cal": "vic3d",
                  ".caldat": "matchid", ".mat": "matlab"}


def _calibration_convert(args) -> int:
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


def _export(args) -> int:
    from workbench.tool_cli import export_command
    return export_command(args)


def _score(args) -> int:
    from workbench.tool_cli import score_command
    return score_command(args)


def _reproduce_star(args) -> int:
    from workbench.experiments.star import star_command
    return star_command(args)


def _gate(args) -> int:
    from workbench.tool_cli import gate_command
    return gate_command(args)


def _parameters(args) -> int:
    from workbench.sweep_cli import parameters_command
    return parameters_command(args)


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
    argv = _join_negative_lists(list(sys.argv[1:] if argv is None else argv))
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exit_:          # argparse: --help (0) or a refused option (2, message printed)
        return exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 2)
    handlers = {("render", "checkerboard"): _render_checkerboard,
                ("reproduce", "agreement"): _reproduce_agreement,
                ("reproduce", "depth-of-field"): _reproduce_depth_of_field,
                ("reproduce", "calibration"): _reproduce_calibration,
                ("calibrate", None): _calibrate,
                ("dic", None): _dic,
                ("stereo", None): _stereo,
                ("reproduce", "dic-accuracy"): _reproduce_dic_accuracy,
                ("reproduce", "paper"): _reproduce_paper,
                ("reproduce", "rigid-motion"): _reproduce_rigid_motion,
                ("reproduce", "bending"): _reproduce_bending,
                ("sweep", None): _sweep,
                ("reproduce", "fig6-causes"): _fig6_causes,
                ("budget", None): _budget,
                ("parameters", None): _parameters,
                ("calibration", "convert"): _calibration_convert,
                ("export", None): _export,
                ("score", None): _score,
                ("gate", None): _gate,
                ("reproduce", "star"): _reproduce_star}
    where = " ".join(filter(None, ("workbench", args.command, getattr(args, "what", None))))
    try:
        with _one_line_warnings(where):
            return handlers[(args.command, getattr(args, "what", None))](args)
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
