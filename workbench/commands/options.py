"""Argument types and input/output checks shared by the ``workbench`` commands: every option is checked when
it is parsed (numbers finite and in range, sizes odd, ...) and every file before the first long computation."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np


#: Renders derive 32-bit sampler seeds as ``seed * 100003 + 2 * view + camera``: seeds up to this fit.
MAX_SEED = (2 ** 32 - 1) // 100003 - 1


#: Most views one checkerboard render may hold (keeps the derived sampler seeds in 32 bits).
MAX_VIEWS = 10_000


def number_arg(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def integer_arg(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def positive_int_arg(text: str) -> int:
    value = integer_arg(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


#: Most calibrations one ``--covariance bootstrap`` may ask for (a typing slip of 40000 would run for a day).
MAX_BOOTSTRAP_DRAWS = 10_000


def draws_arg(text: str) -> int:
    """``--bootstrap-draws``: an integer in [2, MAX_BOOTSTRAP_DRAWS] (a sample covariance needs two draws)."""
    value = integer_arg(text)
    if not 2 <= value <= MAX_BOOTSTRAP_DRAWS:
        raise argparse.ArgumentTypeError(f"must be an integer in [2, {MAX_BOOTSTRAP_DRAWS}], got {value}")
    return value


def views_arg(text: str) -> int:
    value = positive_int_arg(text)
    if value > MAX_VIEWS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_VIEWS}, got {value}")
    return value


def seed_arg(text: str) -> int:
    value = integer_arg(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, {MAX_SEED}] (renders derive 32-bit sampler "
                                         f"seeds from it), got {value}")
    return value


def subset_arg(text: str) -> int:
    value = integer_arg(text)
    if value < 5 or value % 2 == 0:
        raise argparse.ArgumentTypeError(f"must be odd and >= 5 (a subset is 2M + 1 pixels wide), got {value}")
    return value


def strain_window_arg(text: str):
    """``--strain-window``: an odd number of grid points >= 3, ``triangles`` (the paper's Cosserat elements) or
    ``none`` (no strain); returns the int, ``"triangles"`` or None."""
    word = text.strip().lower()
    if word in ("triangles", "none"):
        return None if word == "none" else "triangles"
    value = integer_arg(text)
    if value < 3 or value % 2 == 0:
        raise argparse.ArgumentTypeError(f"must be an odd number of grid points >= 3, 'triangles' or 'none', "
                                         f"got {text!r}")
    return value


def positive_float_arg(text: str) -> float:
    value = number_arg(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def non_negative_float_arg(text: str) -> float:
    value = number_arg(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def zncc_arg(text: str) -> float:
    value = number_arg(text)
    if not -1.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"a ZNCC threshold must be in [-1, 1], got {text!r}")
    return value


def fraction_arg(text: str) -> float:
    value = number_arg(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1], got {text!r}")
    return value


def scale_arg(text: str) -> float:
    value = number_arg(text)
    if not 0 < value <= 4:
        raise argparse.ArgumentTypeError(f"scale must be in (0, 4], got {value}")
    return value


def angle_deg_arg(text: str) -> float:
    value = number_arg(text)
    if not -80.0 <= value <= 80.0:
        raise argparse.ArgumentTypeError(f"must be an angle in [-80, 80] deg, got {text!r}")
    return value


def pattern_arg(text: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"pattern must look like 11x8, got {text!r}") from None
    if a < 2 or b < 2:
        raise argparse.ArgumentTypeError(f"pattern needs at least 2x2 inner corners, got {text!r}")
    return a, b


def pair_arg(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two numbers 'A,B', got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise argparse.ArgumentTypeError(f"expected two finite numbers 'A,B', got {text!r}")
    return a, b


def tilt_pair_arg(text: str) -> tuple[float, float]:
    a, b = pair_arg(text)
    if max(abs(a), abs(b)) > 45.0:
        raise argparse.ArgumentTypeError(f"sensor tilts (alpha,beta) must be within +-45 deg, got {text!r}")
    return a, b


def roi_arg(text: str) -> tuple[int, int, int, int]:
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


def input_file(path: Path, what: str) -> Path:
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what} {path} is a directory, not a file")
    if not path.is_file():
        raise ValueError(f"{what} not found: {path}")
    return path


def existing_ancestor_is_folder(path: Path, what: str) -> None:
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{what} {path}: {parent} is a file, not a folder")
            return


def output_file(path: Path, what: str = "--out") -> Path:
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what} {path} is a directory; give the name of the file to write")
    existing_ancestor_is_folder(path, what)
    return path


def output_folder(path: Path, what: str = "--out") -> Path:
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{what} {path} is a file, not a folder")
    existing_ancestor_is_folder(path, what)
    return path


def glob_files(pattern: str, option: str) -> list[str]:
    import glob

    matches = sorted(glob.glob(pattern))
    if not matches:
        raise ValueError(f"no images match {option} {pattern!r}")
    folders = [m for m in matches if Path(m).is_dir()]
    if folders:
        raise ValueError(f"{option} {pattern!r} matches the directory {folders[0]}; give a pattern of image files")
    return matches


def paired_globs(left_pattern: str, right_pattern: str) -> tuple[list[str], list[str]]:
    left, right = glob_files(left_pattern, "--left"), glob_files(right_pattern, "--right")
    if len(left) != len(right):
        raise ValueError(f"{len(left)} left images but {len(right)} right images: they must pair up "
                         f"(--left {left_pattern!r}, --right {right_pattern!r})")
    same = sorted(set(map(resolved, left)) & set(map(resolved, right)))
    if same:
        raise ValueError(f"--left and --right both match {same[0]}: left and right images must be different files")
    return left, right


def resolved(path) -> str:
    return str(Path(path).resolve())


def size_text(image: np.ndarray) -> str:
    return f"{image.shape[1]} x {image.shape[0]} px"


def read_image_for(path, what: str):
    """An image through the one loader, after checking the path is a file (a directory says so)."""
    from measurement.image_io import read_grey

    return read_grey(input_file(Path(path), what))


def check_subset_fits(subset: int, image: np.ndarray, what: str = "image") -> None:
    if subset > min(image.shape):
        raise ValueError(f"--subset {subset} px does not fit the {size_text(image)} {what}: it must be at most "
                         f"{min(image.shape)} px (the image's smaller side)")


def check_roi_in_image(roi, image: np.ndarray, what: str = "image") -> None:
    if roi is None:
        return
    x0, y0, x1, y1 = roi
    h, w = image.shape
    if x1 > w or y1 > h:
        raise ValueError(f"--roi {x0},{y0},{x1},{y1} reaches outside the {size_text(image)} {what} "
                         f"(need X1 <= {w}, Y1 <= {h})")


def poi_grid(image: np.ndarray, args, mask=None, what: str = "image"):
    """The POI grid of the options, with errors that name the option the user gave (never an implicit ROI)."""
    from measurement.dic import poi_grid

    check_subset_fits(args.subset, image, what)
    check_roi_in_image(args.roi, image, what)
    try:
        return poi_grid(image.shape, args.subset, args.step, roi=args.roi, mask=mask)
    except ValueError as err:
        if args.roi is not None:
            raise ValueError(f"--roi {','.join(map(str, args.roi))}: {err}") from None
        if mask is not None:
            raise ValueError(f"--mask: {err}") from None
        raise ValueError(f"--subset {args.subset} px leaves no point of interest in the {size_text(image)} {what} "
                         f"({err})") from None


def add_auto_roi_options(parser) -> None:
    """``--auto-roi-precision`` and ``--noise-sigma`` of the ``dic`` and ``stereo`` commands (need ``--auto-roi``)."""
    from measurement.dic.roi import DEFAULT_TARGET_PRECISION_PX

    parser.add_argument("--auto-roi-precision", type=positive_float_arg, default=None,
                        help="with --auto-roi: largest noise-limited std of u, v a subset must reach (px), default "
                             f"{DEFAULT_TARGET_PRECISION_PX:g}")
    parser.add_argument("--noise-sigma", type=non_negative_float_arg, default=None,
                        help="with --auto-roi: image noise std (grey levels), default estimated from the reference")


def auto_roi_settings(args):
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
