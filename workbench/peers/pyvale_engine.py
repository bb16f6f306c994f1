"""pyvale's 2-D DIC as a peer engine: ``--engine workbench.peers.pyvale_engine:run``.

:func:`run` is the Python engine entry point that :mod:`workbench.engines` calls; it runs
``pyvale.dic.calculate_2d`` (pyvale >= 2026.10.2, ``pip install '.[peers]'``) on one image pair and leaves
pyvale's own CSV at the result path. :func:`read_result` reads that CSV into this project's convention; it
needs numpy only, not pyvale, so a result can be scored where pyvale is not installed.

pyvale API used
---------------
``pyvale.dic.calculate_2d(reference, deformed, roi_mask, seed, subset_size, subset_step,
correlation_criteria, shape_function, interpolation_routine, ..., num_threads, max_displacement, method, ...,
output_basepath, output_binary, output_prefix, output_delimiter, output_below_threshold, ...,
image_filter_kernel, ..., print_level) -> None``: images as paths (TIFF or BMP only) or as arrays (uint8,
uint16, uint32 or float32); ``roi_mask`` a bool image, a subset is computed only where all its pixels are in
the mask (``partial_subset=1``); ``seed`` the reliability-guided start points as ``[(x, y), ...]`` subset
centres; results written as ``<output_basepath>/<output_prefix><deformed name>.csv``, nothing returned.

This engine runs it with ZNSSD, affine (``order=1``) or quadratic (``order=2``) shape functions, B-spline
interpolation, the multi-window reliability-guided scan, the Gaussian prefilter off
(``image_filter_kernel=1``; pyvale's default is a 5 px kernel) and ``print_level=0`` (no banner, no progress
bars). Any other ``calculate_2d`` keyword can be passed through ``**options`` (e.g. ``threshold``,
``precision``, ``max_iterations``, ``max_displacement``). pyvale's stop test is relative: a step counts as
converged when ``|dp| / |p| < precision`` and the relative change of the cost is below ``precision``.

Known behaviour: a noise-induced bias towards the half pixel
-----------------------------------------------------------
pyvale's optimiser is a forward-additive Gauss-Newton / Levenberg-Marquardt iteration (``dicoptimizer.cpp``):
its steepest-descent images are the gradients of the *deformed* image, interpolated by the cubic B-spline at
the same warped positions as the grey values. The interpolated noise ``n(t)`` of the deformed image and its
interpolated gradient ``n'(t)`` are then correlated, ``E[n n'] = sigma^2 S'(t) / 2`` with
``S(t) = sum_k w_k(t)^2`` the interpolation weights' sum of squares at the sub-pixel fraction ``t``, and the
iteration settles where the expected cost is lowest: shifted towards the half pixel (``S`` is smallest
there) by ``-sigma^2 S'(t) / (2 <f_x^2>)``. This project's IC-GN takes its gradients from the reference
image and has no such term. Measured (512 px Fourier-shifted pair, 4 px speckle, subset 33, affine, float
images, this engine's settings), ``u`` bias of pyvale / of ``workbench.engines:ours``:

* noise-free: +0.0018 / +0.0003 px at a 0.25 px shift (the cubic spline's own interpolation bias: our IC-GN
  with its bicubic B-spline gives +0.0019);
* read noise 3 grey in both images: +0.0133 / +0.0002 px (std 0.0076 px for both), and our IC-GN with the
  same cubic spline as pyvale's: +0.0019 (so it is the forward-additive iteration, not the spline); noise in
  the deformed image only: +0.0133, in the reference only: +0.0017; noise 1.5 grey: +0.0047 (the excess over the
  noise-free bias scales as sigma^2: 0.0115 and 0.0029 px); predicted from the formula with the clean
  image's <f_x^2> = 313 grey^2/px^2: +0.0108 and +0.0027 px;
* the excess follows -S'(t): +0.008, +0.0115, +0.006, 0.000 px at 0.1, 0.25, 0.4, 0.5 px, odd in the shift
  (-0.0135 at -0.25 px total) and periodic (+0.0138 at 1.25 px total); 8-bit images give the same;
* unchanged by ``precision=1e-6`` or ``max_iterations=200`` (it is not the stop test), and not from the
  hand-over of the images (float32, no normalisation or clipping: the noise-free pair matches our bicubic);
* with pyvale's own default Gaussian prefilter (``image_filter_kernel=5``, sigma 1 px), which this engine
  turns off, the bias falls to +0.0003 px and the std rises to 0.0087 px (the filter correlates the noise and
  damps the high frequencies the spline gets wrong).

``benchmarks/peer_pyvale.py`` puts the two engines side by side (``reports/peer_pyvale/``).

pyvale 2026.10.2's ``interpolation_routine="HERMITE"`` crashes the process (its ``Hermite`` constructor
sizes its image buffer from width and height before it sets them), so this engine refuses it on that
version with a ValueError instead.

Side effects of pyvale that this engine undoes: ``import pyvale`` creates an empty ``plotter_log.log`` in the
current folder (removed again, :func:`remove_stray_log`), and its C++ engine takes over SIGINT for good
(Python's handler is put back after each run). ``threads`` sets pyvale's OpenMP thread count process-wide.

Result file (pyvale's CSV, comma-separated)
-------------------------------------------
Header ``"subset_x","subset_y","disp_u","disp_v","disp_mag","converged","cost_zncc","ftol","xtol","num_iter",``
(quoted names, and a trailing delimiter that the data rows do not have), one row per subset of the grid:

* ``subset_x``, ``subset_y``: subset centre in the reference image, px;
* ``disp_u``, ``disp_v``: displacement of that subset, px, ``nan`` where the ZNCC is below ``threshold``
  (0.9 by default);
* ``disp_mag`` px; ``converged`` 0/1; ``cost_zncc``; ``ftol``, ``xtol`` (last relative steps); ``num_iter``.

The grid is pyvale's own: subset corners at multiples of ``subset_step`` from the image origin, i.e. centres
at ``k * step + (subset - 1) / 2``, not aligned to the ROI's corner.

Convention, and how it was established
--------------------------------------
pyvale's coordinates and displacements are already this project's: ``x`` = column, ``y`` = row, 0-based,
pixel centres at integer coordinates, and ``u = deformed position - reference position`` at the reference
(Lagrangian) subset centre. :func:`read_result` therefore converts nothing but the validity.

* Source: the subset grid stores ``corner + size / 2 - 0.5`` as the centre (``dicsubset.cpp``), where the
  corner is the index of the subset's first pixel column (``idx = y * width + x``).
* Experiment 1 (shift and sign): a Fourier-shifted pair (256 x 256 px, 4 px speckle) moved by
  ``(+0.37, -0.21)`` px gave ``disp_u = +0.371``, ``disp_v = -0.212`` px (affine, 33 px subsets): same
  sign, ``u`` along columns.
* Experiment 2 (origin): an exact Gaussian-speckle pair with ``u = 0.01 (x - 100)``,
  ``v = -0.008 (y - 140)`` (256 x 256 px, 529 subsets of 33 px) gave, at the reported coordinates, an rms
  error of 0.0010 px in ``u`` and 0.0012 px in ``v`` (quadratic: 0.0013, 0.0013); evaluating the truth at
  coordinates shifted by +-0.5 px instead gives 0.005 px in ``u`` and 0.004 px in ``v``, and by +-1 px
  0.010 and 0.008 px. The least-squares coordinate offset implied is -0.007 px in x and +0.02 px in y: zero.
  ``tests/test_peer_pyvale.py`` repeats both checks.
"""
from __future__ import annotations

import contextlib
import csv
import importlib.metadata
import inspect
import logging
import math
import signal
import tempfile
import threading
from pathlib import Path

import numpy as np

RESULT_FORMAT = "pyvale"

#: The CSV columns :func:`read_result` needs.
REQUIRED_COLUMNS = ("subset_x", "subset_y", "disp_u", "disp_v", "converged")

#: Shape function by this project's ``order``.
SHAPE_FUNCTIONS = {1: "AFFINE", 2: "QUAD"}

#: pyvale's interpolant by this project's ``interpolation`` name: its B-spline is cubic.
INTERPOLANTS = {"bicubic": "BSPLINE"}

#: The instrument settings this engine offers (:func:`workbench.engines.check_settings` refuses others up
#: front): no biquintic interpolant, and no Gaussian pre-filter of a given sigma (pyvale's
#: ``image_filter_kernel`` is a kernel size, passed as an option of its own).
SUPPORTED_SETTINGS = {"order": tuple(SHAPE_FUNCTIONS), "interpolation": tuple(INTERPOLANTS),
                      "prefilter_sigma_px": ()}

#: Array dtypes pyvale's in-memory path accepts; others are passed as float32.
_PYVALE_DTYPES = (np.uint8, np.uint16, np.uint32, np.float32)

#: ``calculate_2d`` keywords this engine sets itself: they fix the inputs and the result file it reads.
_RESERVED = frozenset({
    "reference", "deformed", "roi_mask", "seed", "subset_size", "subset_step", "shape_function", "num_threads",
    "output_basepath", "output_binary", "output_prefix", "output_delimiter", "output_below_threshold",
})

#: Defaults of this engine where they differ from pyvale's, each overridable through ``**options``.
_DEFAULTS = {
    "correlation_criteria": "ZNSSD",
    "interpolation_routine": "BSPLINE",
    "method": "MULTIWINDOW_RG",
    "image_filter_kernel": 1,   # no Gaussian prefilter: the other engines see the raw images too
    "print_level": 0,           # no banner or progress bars on stdout/stderr
}

#: The log file ``import pyvale`` opens in the current folder (see :func:`remove_stray_log`).
STRAY_LOG = Path("plotter_log.log")

#: pyvale's default search radius, px; smaller for images too small for it (it needs 2 r < width, height).
_MAX_DISPLACEMENT_PX = 64


def run(reference, deformed, out, *, subset_px: int = 33, step_px: int = 8, roi_xyxy_px=None, order: int = 1,
        interpolation: str = "bicubic", threads: int = 1, **options) -> Path:
    """Run pyvale's 2-D DIC on one image pair and write its CSV to ``out`` (atomically).

    Parameters
    ----------
    reference, deformed : str or Path
        Image files of the same size, any format :func:`measurement.image_io.read_grey` reads (they are
        passed to pyvale as arrays, because pyvale itself reads TIFF and BMP only).
    out : str or Path
        The result file to write: pyvale's CSV (see the module docstring); its folder is created if missing.
    subset_px : int
        Subset side, px; odd.
    step_px : int
        Grid step, px, ``<= subset_px``.
    roi_xyxy_px : (x0, y0, x1, y1) or None
        Inclusive pixel bounds of the subset centres (x = column, y = row, pixel centres at integers); None for
        the whole image. Only subsets whose pixels all lie in the image are computed, and their centres are
        pyvale's grid points ``k * step_px + (subset_px - 1) / 2`` inside these bounds.
    order : int
        Shape function: 1 = affine, 2 = quadratic.
    interpolation : str
        ``"bicubic"`` (pyvale's cubic B-spline, ``interpolation_routine="BSPLINE"``), the only one of this
        project's interpolants pyvale has; ``interpolation_routine`` in ``options`` overrides it.
    threads : int
        OpenMP threads for pyvale (it sets them process-wide).
    **options
        Further ``pyvale.dic.calculate_2d`` keywords (``threshold``, ``precision``, ``max_iterations``,
        ``max_displacement`` px, ``interpolation_routine``, ``print_level``, ...), overriding this engine's
        defaults. Keywords that fix the inputs or the result file are refused.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ModuleNotFoundError
        If pyvale is not installed.
    ValueError
        On a bad setting, unreadable images, images of different sizes, an ROI that holds no subset, or
        ``interpolation_routine="HERMITE"`` on a pyvale it crashes.
    TypeError
        On an option ``calculate_2d`` does not take or that this engine sets itself.
    """
    from labio.atomic import atomic_write_bytes
    from measurement.image_io import read_grey

    dic = import_pyvale_dic()
    subset_px, step_px = int(subset_px), int(step_px)
    if order not in SHAPE_FUNCTIONS:
        raise ValueError(f"order must be 1 (affine) or 2 (quadratic), got {order!r}")
    if interpolation not in INTERPOLANTS:
        raise ValueError(f"pyvale engine: interpolation {interpolation!r} is not offered by pyvale; it has "
                         f"{', '.join(INTERPOLANTS)} (cubic B-spline)")
    options = _check_options(dic, options)   # before reading images: a typo fails at once
    ref_image, def_image = _pyvale_arrays(read_grey(reference), read_grey(deformed), reference, deformed)
    mask = roi_mask(ref_image.shape, subset_px, roi_xyxy_px)
    seed = seed_point(mask, subset_px, step_px)
    settings = {**_DEFAULTS, "interpolation_routine": INTERPOLANTS[interpolation],
                "max_displacement": _max_displacement(ref_image.shape), **options}

    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="pyvale-") as work, _keep_python_sigint():
        dic.calculate_2d(ref_image, def_image, mask, [seed], subset_size=subset_px, subset_step=step_px,
                         shape_function=SHAPE_FUNCTIONS[order], num_threads=int(threads), output_basepath=work,
                         output_binary=False, output_prefix="dic_results_", output_delimiter=",",
                         output_below_threshold=False, **settings)
        produced = sorted(Path(work).glob("*.csv"))
        if len(produced) != 1:
            raise RuntimeError(f"pyvale wrote {len(produced)} CSV files, expected 1: "
                               f"{[p.name for p in produced]}")
        # Copy, not rename: the temporary folder may be on another filesystem than ``out``.
        atomic_write_bytes(out, produced[0].read_bytes())
    return out


def read_result(path) -> dict:
    """Read pyvale's 2-D DIC CSV into this project's convention.

    Parameters
    ----------
    path : str or Path
        A CSV written by ``pyvale.dic.calculate_2d`` (or by :func:`run`).

    Returns
    -------
    dict
        ``x_px``, ``y_px`` (float arrays, px): subset centres in the reference image, x = column, y = row,
        pixel centres at integer coordinates; ``u_px``, ``v_px`` (float arrays, px): displacement = deformed
        position - reference position, NaN where not valid; ``valid`` (bool array): converged and above
        pyvale's ZNCC threshold; ``tool``: ``"pyvale <installed version>"``. pyvale's convention is already
        this one (module docstring), so no value is shifted.

    Raises
    ------
    ValueError
        Naming the file, when it is empty, lacks a required column or holds a value that is not a number.
    """
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            # Blank lines carry nothing (and pyvale writes none); skipping them keeps line numbers honest enough.
            rows = [row for row in csv.reader(handle) if row]
    except OSError as err:
        raise ValueError(f"cannot read pyvale result {path}: {err.strerror or err}") from None
    except UnicodeDecodeError:
        raise ValueError(f"pyvale result {path} is not a text CSV") from None
    if not rows:
        raise ValueError(f"pyvale result {path} is empty (no header line)")
    header = [name.strip() for name in rows[0]]
    # pyvale ends the header with a delimiter: drop the empty name it leaves, the rows have no such field.
    while header and not header[-1]:
        header.pop()
    missing = [name for name in REQUIRED_COLUMNS if name not in header]
    if missing:
        raise ValueError(f"pyvale result {path} has no column {', '.join(repr(m) for m in missing)} "
                         f"(columns: {', '.join(header) or 'none'})")
    columns = {name: _column(rows, header.index(name), name, path) for name in REQUIRED_COLUMNS}
    u, v = columns["disp_u"], columns["disp_v"]
    valid = (columns["converged"] == 1) & np.isfinite(u) & np.isfinite(v)
    return {
        "x_px": columns["subset_x"],
        "y_px": columns["subset_y"],
        "u_px": np.where(valid, u, np.nan),
        "v_px": np.where(valid, v, np.nan),
        "valid": valid,
        "tool": f"pyvale {_pyvale_version()}",
    }


def roi_mask(shape: tuple[int, int], subset_px: int, roi_xyxy_px=None) -> np.ndarray:
    """The pyvale ROI mask whose whole subsets have their centres in ``roi_xyxy_px``.

    pyvale computes a subset only where all its pixels are in the mask, so the mask is the centre box grown by
    half a subset on every side (clipped to the image).

    Parameters
    ----------
    shape : (rows, cols)
        Image size, px.
    subset_px : int
        Subset side, px; odd.
    roi_xyxy_px : (x0, y0, x1, y1) or None
        Inclusive bounds of the subset centres, px (x = column); non-integer bounds are rounded inwards.

    Returns
    -------
    ndarray of bool, shape ``shape``
    """
    rows, cols = (int(n) for n in shape)
    half = int(subset_px) // 2
    mask = np.zeros((rows, cols), dtype=bool)
    if roi_xyxy_px is None:
        mask[:] = True
        return mask
    if len(roi_xyxy_px) != 4:
        raise ValueError(f"roi_xyxy_px must be (x0, y0, x1, y1), got {roi_xyxy_px!r}")
    bounds = [float(b) for b in roi_xyxy_px]
    if not all(math.isfinite(b) for b in bounds):
        raise ValueError(f"roi_xyxy_px must be finite, got {roi_xyxy_px!r}")
    x0, y0 = math.ceil(bounds[0]), math.ceil(bounds[1])
    x1, y1 = math.floor(bounds[2]), math.floor(bounds[3])
    if x1 < x0 or y1 < y0:
        raise ValueError(f"roi_xyxy_px {roi_xyxy_px!r} is empty: it needs x0 <= x1 and y0 <= y1")
    mask[max(y0 - half, 0):max(y1 + half + 1, 0), max(x0 - half, 0):max(x1 + half + 1, 0)] = True
    return mask


def seed_point(mask: np.ndarray, subset_px: int, step_px: int) -> tuple[int, int]:
    """The reliability-guided seed: the grid subset wholly inside ``mask`` nearest the mask's centre.

    Parameters
    ----------
    mask : ndarray of bool, shape (rows, cols)
        A rectangular ROI mask (as :func:`roi_mask` makes).
    subset_px, step_px : int
        Subset side and grid step, px.

    Returns
    -------
    (x, y) : tuple of int
        Subset centre, px, on pyvale's grid (corners at multiples of ``step_px``).

    Raises
    ------
    ValueError
        If no grid subset fits in the mask.
    """
    ys, xs = np.nonzero(mask)
    if xs.size == 0:
        raise ValueError("the ROI holds no pixel of the image")
    x = _centre_on_grid(int(xs.min()), int(xs.max()), subset_px, step_px)
    y = _centre_on_grid(int(ys.min()), int(ys.max()), subset_px, step_px)
    if x is None or y is None:
        raise ValueError(f"the ROI (x {xs.min()}..{xs.max()}, y {ys.min()}..{ys.max()} px with the subsets' "
                         f"borders) holds no whole {subset_px} px subset on pyvale's {step_px} px grid")
    return x, y


# ------------------------------------------------------------------------------------------------------------
def _centre_on_grid(first: int, last: int, subset_px: int, step_px: int) -> int | None:
    """Centre of the grid subset spanning pixels ``[first, last]`` nearest its middle; None if none fits."""
    k_lo = -(-first // step_px)                    # first corner on the grid at or after ``first``
    k_hi = (last - subset_px + 1) // step_px       # last corner whose subset ends by ``last``
    if k_hi < k_lo:
        return None
    k = min(max(round(((first + last) / 2 - (subset_px - 1) / 2) / step_px), k_lo), k_hi)
    return k * step_px + (subset_px - 1) // 2


def _pyvale_arrays(ref: np.ndarray, deformed: np.ndarray, ref_path, def_path) -> tuple[np.ndarray, np.ndarray]:
    """Both images in one dtype pyvale accepts: their own if it does, else float32 (exact for 8/16-bit)."""
    if ref.shape != deformed.shape:
        raise ValueError(f"images differ in size: {ref_path} is {ref.shape[1]} x {ref.shape[0]} px, "
                         f"{def_path} is {deformed.shape[1]} x {deformed.shape[0]} px")
    dtype = ref.dtype if ref.dtype == deformed.dtype and ref.dtype in _PYVALE_DTYPES else np.float32
    return np.ascontiguousarray(ref, dtype=dtype), np.ascontiguousarray(deformed, dtype=dtype)


def _max_displacement(shape: tuple[int, int]) -> int:
    """pyvale's default search radius, px, reduced so that ``2 r`` fits in the image as pyvale requires."""
    return max(1, min(_MAX_DISPLACEMENT_PX, (min(shape) - 1) // 2))


def _check_options(dic, options: dict) -> dict:
    """The ``**options`` that may go to ``calculate_2d``; TypeError naming any that may not, ValueError for the
    Hermite interpolator of the pyvale versions it crashes (module docstring)."""
    reserved = sorted(set(options) & _RESERVED)
    if reserved:
        raise TypeError(f"pyvale engine: {', '.join(reserved)} is set by the engine itself "
                        f"(use subset_px, step_px, roi_xyxy_px, order, threads)")
    accepted = set(inspect.signature(dic.calculate_2d).parameters) - _RESERVED
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise TypeError(f"pyvale engine: unknown option(s) {', '.join(unknown)}; "
                        f"pyvale.dic.calculate_2d takes {', '.join(sorted(accepted))}")
    routine = options.get("interpolation_routine")
    routine = str(getattr(routine, "value", routine)).upper() if routine is not None else None
    version = _pyvale_version()
    if routine == "HERMITE" and _version_tuple(version) <= _HERMITE_CRASHES_UP_TO:
        raise ValueError(f"pyvale engine: interpolation_routine='HERMITE' crashes pyvale {version} (a segmentation "
                         f"fault: its Hermite interpolator sizes its buffer before it knows the image size); "
                         f"use 'BSPLINE'")
    return dict(options)


#: The newest pyvale whose HERMITE interpolator is known to crash the process.
_HERMITE_CRASHES_UP_TO = (2026, 10, 2)


def _version_tuple(version: str) -> tuple[int, ...]:
    """``'2026.10.2'`` -> ``(2026, 10, 2)``: the leading integers of each dotted part; ``()`` if there are none
    (an unknown version counts as an old one)."""
    parts = []
    for part in version.split("."):
        digits = ""
        for ch in part:
            if not ch.isdigit():
                break
            digits += ch
        if not digits:
            break
        parts.append(int(digits))
    return tuple(parts)


def _column(rows: list[list[str]], index: int, name: str, path: Path) -> np.ndarray:
    """Column ``index`` of the data rows as float64 ('nan' and '-nan' read as NaN)."""
    values = np.empty(len(rows) - 1)
    for line, row in enumerate(rows[1:], start=2):
        try:
            values[line - 2] = float(row[index])
        except (IndexError, ValueError):
            raise ValueError(f"pyvale result {path} line {line}: column {name!r} is missing or not a number"
                             ) from None
    return values


def import_pyvale_dic():
    """``pyvale.dic``, imported only when an engine runs (it is an optional, heavy dependency: ~5 s)."""
    had_stray_log = STRAY_LOG.exists()
    try:
        import pyvale.dic as dic
    except ModuleNotFoundError as err:
        if err.name is None or not err.name.startswith("pyvale"):
            raise
        raise ModuleNotFoundError("the pyvale peer engine needs pyvale: pip install '.[peers]'",
                                  name="pyvale") from None
    remove_stray_log(had_stray_log)
    return dic


def remove_stray_log(existed_before: bool) -> None:
    """Undo pyvale's import-time ``plotter_log.log`` in the current folder, if the import just created it.

    ``import pyvale`` opens a ``logging.FileHandler("plotter_log.log")`` (``pyvale.sensorsim``) in whatever
    folder the process runs in, e.g. a checkout. Its handlers are closed and detached and the file is removed
    when it did not exist before (``existed_before``) and is still empty; a log the user already had is kept.
    """
    path = STRAY_LOG.resolve()
    if existed_before or not path.is_file() or path.stat().st_size:
        return
    loggers = [logging.getLogger()] + [lg for lg in logging.Logger.manager.loggerDict.values()
                                       if isinstance(lg, logging.Logger)]
    for logger in loggers:
        for handler in list(logger.handlers):
            if isinstance(handler, logging.FileHandler) and Path(handler.baseFilename) == path:
                logger.removeHandler(handler)
                handler.close()
    path.unlink(missing_ok=True)


@contextlib.contextmanager
def _keep_python_sigint():
    """Give SIGINT back to Python after pyvale's engine, which installs its own C handler and keeps it.

    pyvale's handler only sets a flag that its loops poll, so without this a later Ctrl+C in the process
    would be swallowed. Handlers can only be set from the main thread; elsewhere nothing is done.
    """
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGINT) if main else None
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _pyvale_version() -> str:
    """The installed pyvale's version, read from its metadata (no import); 'unknown version' if absent."""
    try:
        return importlib.metadata.version("pyvale")
    except importlib.metadata.PackageNotFoundError:
        return "(unknown version)"
