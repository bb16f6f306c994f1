"""Parametric bootstrap of a stereo calibration's parameter covariance.

The linear covariance ``s^2 (J^T J)^-1`` that :func:`~measurement.calibration.stepwise.calibrate_stereo` keeps is
first order in the corner noise. On narrow-field rigs (the paper's: fx ~ 10 900 px, tilt and principal point
correlated to |r| ~ 0.9999) the estimate is not linear in the noise beyond ~0.01 px of corner noise, and the
linear covariance then under-states the spread of the calibration 1.5-2.2 x at 0.05 px
(``tests/test_calibration_uncertainty.py``). The bootstrap measures the spread instead of linearising it::

    for k = 1..K:
        corners_k = the fitted model's projections of the board at the fitted poses (both cameras)
                    + Gaussian noise of the fitted residual's standard deviation, per camera,
                    only where a corner was found
        theta_k   = calibrate_stereo(corners_k, same options)
    C = sample covariance of (theta_k - theta_hat)                                    (k, k)

The draws repeat the whole stepwise procedure (initialisation included), so whatever the estimator does with
noise of this size, the draws do too -- including, rarely, stopping in a worse local minimum of the
tilt/principal-point valley (the paper's rig at 0.05 px of corner noise: 2 of 200 calibrations). That is a failure of
the procedure, not the scatter of the least-squares estimate. In the bootstrap's world the truth is known (the fitted
parameters), so every draw is also solved from there: where that reaches a lower cost by more than
:data:`WRONG_MINIMUM_CHI2` (in units of the residual variance), the draw stopped in a wrong minimum; it is counted
(``wrong_minimum``, with a warning) and its parameters are those of the better minimum.

What it achieves (``tests/test_calibration_uncertainty.py``, the paper's rig, 12 views, Monte Carlo spread over 40
calibrations / median predicted sigma of X, Y, Z): at 0.005 px 1.03 1.10 1.03 (linear: 1.04 1.12 1.03), at 0.02 px
1.14 1.19 1.12 (linear 1.06 1.17 1.06), the displacement's alike. At 0.05 px it does NOT repair the linear
covariance's under-statement (bootstrap 1.91 1.64 2.21, linear 1.66 1.46 2.04): the spread there is carried by ~5 % of
calibrations 5-13 sigma out along the valley (most of them global minima, so a real heavy tail), and a bootstrap
around one estimate meets such draws at a rate that depends on where that estimate lies (a 200-draw bootstrap: 1.5
2.1 1.6). Without those ~5 % the spread is 0.96 1.16 0.97 of the linear sigma. The other way round, one far draw
in 20 can widen a bootstrap covariance tenfold: on the quarter-scale rig (12 views, 0.035 px) a draw at a second,
lower minimum (alpha 4.7 deg against 0.5 deg) made the sigma of a mean displacement magnitude 24 x the linear
one and the spread of 20 calibrations. Use it as a check of a calibration's fragility (``wrong_minimum``, far
draws), not as a cure for the nonlinearity.

The stereo rotation enters as the difference of the rotation vectors of
``R_right_from_left``, ``rvec(R_k) - rvec(R_hat)``: the convention of the linear covariance and of its
propagation (:mod:`measurement.uncertainty.calibration` perturbs ``R = from_rotvec(rvec + d)``).

The noise level is the fitted residual's: ``sigma_c^2 = |r_c|^2 / (2 n_c) * m / (m - n)`` per coordinate of camera
c (``n_c`` corners found, ``m`` residuals and ``n`` parameters of the whole stereo problem: the usual
degrees-of-freedom correction, shared). This presumes what the linear covariance presumes too: corner errors
independent, Gaussian, alike within a camera, and the model right (a lens term the model lacks shows in the
residual as if it were noise).

Cost: K calibrations (~1.4 s each for 12 views of an 11 x 8 board, ~2.5 s for 30; ``workers`` spreads them over
processes). Every draw is seeded by ``(seed, k)``, so a bootstrap is reproducible and independent of ``workers``.
A draw the calibration refuses (:class:`~measurement.calibration.stepwise.CalibrationError`) is left out and
counted; more than :data:`MAX_FAILED_FRACTION` of them refuse the whole bootstrap.
"""
from __future__ import annotations

import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from measurement.calibration.stepwise import (
    STEREO_PARAMETER_NAMES,
    CalibrationError,
    StereoCalibration,
    calibrate_stereo,
    free_intrinsics,
    project_views,
    solve_stereo_problem,
    stereo_problem,
)

__all__ = ["LINEAR", "MIN_DRAWS", "MAX_FAILED_FRACTION", "WRONG_MINIMUM_CHI2", "BootstrapCovariance",
           "bootstrap_estimator",
           "parse_estimator", "parameter_vector", "residual_sigma_px", "synthetic_corners", "bootstrap_covariance",
           "with_bootstrap_covariance"]

#: The estimator of the covariance ``calibrate_stereo`` keeps.
LINEAR = "linear"
#: Fewest draws a bootstrap covariance may come from (a (k, k) sample covariance of fewer than k + 1 draws is
#: singular; 20 draws give each sigma to ~16 %, 40 to ~11 %).
MIN_DRAWS = 2
#: Largest share of draws the calibration may refuse before the bootstrap is refused too (leaving out many draws
#: would keep only the well-behaved ones and under-state the spread).
MAX_FAILED_FRACTION = 0.1
#: A draw's stepwise solution whose cost exceeds that of the solve started at the fitted parameters by more than this
#: many residual variances (Delta chi^2) stopped in a wrong minimum. The same minimum reached from two starts
#: differs by ~1e-9 of the cost (~1e-5 in chi^2); the wrong minima seen on the paper's rig lie 5-13 higher.
WRONG_MINIMUM_CHI2 = 1.0
_BOOTSTRAP_RE = re.compile(r"bootstrap \((\d+) draws\)")


def bootstrap_estimator(draws: int) -> str:
    """``"bootstrap (K draws)"``: the estimator name a bootstrap covariance of ``draws`` calibrations carries."""
    return f"bootstrap ({int(draws)} draws)"


def parse_estimator(text: str) -> tuple[str, int | None]:
    """``"linear"`` -> ("linear", None); ``"bootstrap (40 draws)"`` -> ("bootstrap", 40); ValueError otherwise."""
    if text == LINEAR:
        return LINEAR, None
    m = _BOOTSTRAP_RE.fullmatch(text)
    if m is None:
        raise ValueError(f"unknown covariance estimator {text!r}: expected 'linear' or 'bootstrap (K draws)'")
    draws = int(m.group(1))
    if draws < MIN_DRAWS:
        raise ValueError(f"covariance estimator {text!r}: a bootstrap needs at least {MIN_DRAWS} draws")
    return "bootstrap", draws


@dataclass(frozen=True)
class BootstrapCovariance:
    """The result of :func:`bootstrap_covariance`.

    Attributes
    ----------
    covariance : ndarray, shape (k, k)
        Sample covariance (ddof = 1) of the draws' parameters, units of the parameters (px, deg, 1, rad, mm).
    names : tuple of k str
        Row names, as :attr:`StereoCalibration.covariance_names`.
    deviations : ndarray, shape (K, k)
        Each successful draw's parameters minus the fitted ones (rotation: difference of rotation vectors).
    corner_sigma_px : dict
        ``{"left": float, "right": float}``: the noise drawn, px per coordinate.
    draws : int
        Successful draws (rows of ``deviations``).
    failed : int
        Draws the calibration refused (left out).
    not_converged : int
        Successful draws whose least squares warned that it did not converge (kept).
    wrong_minimum : int
        Draws whose stepwise solution stopped in a worse minimum than the solve from the fitted parameters reached
        (module docstring); their deviations are the better minimum's.
    seed : int
    """

    covariance: np.ndarray
    names: tuple
    deviations: np.ndarray
    corner_sigma_px: dict
    draws: int
    failed: int
    not_converged: int
    wrong_minimum: int
    seed: int

    @property
    def mean_deviation(self) -> np.ndarray:
        """(k,) mean of the draws about the fitted parameters: the estimator's bias at the fit, to first order."""
        return self.deviations.mean(axis=0)


def _names(cal: StereoCalibration) -> tuple[str, ...]:
    names = tuple(cal.covariance_names or ())
    if names:
        return names
    free = free_intrinsics(cal.model, cal.lens)
    return tuple(f"left.{n}" for n in free) + tuple(f"right.{n}" for n in free) + STEREO_PARAMETER_NAMES


def parameter_vector(cal: StereoCalibration, names) -> np.ndarray:
    """(k,) the calibration's values of ``names`` (``left.<intrinsic>``, ``right.<intrinsic>``, the stereo pose:
    rotation vector of ``R_right_from_left`` in rad, ``T_right_from_left_mm`` in mm)."""
    rvec = Rotation.from_matrix(np.asarray(cal.R_right_from_left, float)).as_rotvec()
    T = np.asarray(cal.T_right_from_left_mm, float).ravel()
    out = []
    for name in names:
        if name in STEREO_PARAMETER_NAMES:
            i = STEREO_PARAMETER_NAMES.index(name)
            out.append(rvec[i] if i < 3 else T[i - 3])
        else:
            side, _, what = name.partition(".")
            out.append(getattr(getattr(cal, side).camera, what))
    return np.array(out, float)


def _found(points: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(points), axis=-1)


def residual_sigma_px(cal: StereoCalibration, points_left: np.ndarray, points_right: np.ndarray,
                      board_mm: np.ndarray) -> dict:
    """Standard deviation per image coordinate of each camera's corner noise, from the fit's residual (px).

    ``sigma_c^2 = |r_c|^2 / (2 n_c) * m / (m - n)``: camera c's mean squared residual per coordinate over its
    ``n_c`` found corners, with the degrees-of-freedom correction of the whole stereo problem (``m`` residuals of
    found corners, ``n`` = shared parameters + 6 per view).

    Returns
    -------
    dict
        ``{"left": float, "right": float}``, px.
    """
    board_mm = np.asarray(board_mm, float)
    sq, n_found = {}, {}
    for side, pts in (("left", points_left), ("right", points_right)):
        pts = np.asarray(pts, float)
        c = getattr(cal, side)
        r = project_views(c.camera, c.rvecs, c.tvecs_mm, board_mm) - pts
        f = _found(pts)
        sq[side] = float(np.sum(r[f] ** 2))
        n_found[side] = int(f.sum())
    m = 2 * (n_found["left"] + n_found["right"])
    n = len(_names(cal)) + 6 * len(np.asarray(points_left))
    if m <= n:
        raise CalibrationError(f"{m} corner coordinates cannot determine {n} parameters: no residual noise level")
    dof = m / (m - n)
    return {s: float(np.sqrt(sq[s] / (2 * n_found[s]) * dof)) for s in ("left", "right")}


def synthetic_corners(cal: StereoCalibration, found_left: np.ndarray, found_right: np.ndarray, board_mm: np.ndarray,
                      sigma_px: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One draw of corners: the fitted projections of the board at the fitted poses plus Gaussian noise.

    Parameters
    ----------
    cal : StereoCalibration
    found_left, found_right : ndarray of bool, shape (V, N)
        Where each camera found a corner; the others stay missing (NaN), as in the data.
    board_mm : ndarray, shape (N, 3), mm
    sigma_px : dict
        ``{"left": float, "right": float}``, px per coordinate.
    rng : numpy.random.Generator

    Returns
    -------
    tuple of two ndarrays, shape (V, N, 2), px
    """
    out = []
    for side, found in (("left", found_left), ("right", found_right)):
        c = getattr(cal, side)
        exact = project_views(c.camera, c.rvecs, c.tvecs_mm, np.asarray(board_mm, float))
        noisy = exact + rng.normal(0.0, sigma_px[side], exact.shape)
        out.append(np.where(np.asarray(found)[..., None], noisy, np.nan))
    return out[0], out[1]


def _draw(args) -> tuple[np.ndarray | None, bool, bool]:
    """One bootstrap calibration: (parameters (k,) or None if refused, converged, stopped in a wrong minimum).
    Module level: picklable."""
    cal, found_l, found_r, board_mm, sigma_px, seed, k, names, options, s2 = args
    rng = np.random.default_rng([seed, k])
    pl, pr = synthetic_corners(cal, found_l, found_r, board_mm, sigma_px, rng)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            again = calibrate_stereo(pl, pr, board_mm, model=cal.model, lens=cal.lens, **options)
        except CalibrationError:
            return None, False, False
        converged = not any("did not converge" in str(w.message) for w in caught)
        # the same corners solved from this world's truth (the fitted parameters): a lower minimum there means the
        # stepwise procedure stopped in a wrong one
        fn, x_hat, n_shared, rows = stereo_problem(cal, pl, pr, board_mm)
        better = solve_stereo_problem(fn, x_hat, n_shared, rows, options.get("solver", "schur-lm"))
    fn_again, x_again, _, _ = stereo_problem(again, pl, pr, board_mm)
    wrong = float(np.sum(fn_again(x_again) ** 2) - np.sum(fn(better) ** 2)) > WRONG_MINIMUM_CHI2 * s2
    if not wrong:
        return parameter_vector(again, names), converged, False
    free = free_intrinsics(cal.model, cal.lens)
    nl = len(free)
    index = {**{f"left.{n}": i for i, n in enumerate(free)}, **{f"right.{n}": nl + i for i, n in enumerate(free)},
             **{n: 2 * nl + i for i, n in enumerate(STEREO_PARAMETER_NAMES)}}
    return np.array([better[index[n]] for n in names]), converged, True


def bootstrap_covariance(cal: StereoCalibration, points_left: np.ndarray, points_right: np.ndarray,
                         board_mm: np.ndarray, image_size: tuple[int, int], *, draws: int = 40, seed: int = 0,
                         tilt_guess_left_deg: tuple[float, float] = (0.0, 0.0),
                         tilt_guess_right_deg: tuple[float, float] = (0.0, 0.0), joint: bool = True,
                         image_size_right: tuple[int, int] | None = None, solver: str = "schur-lm",
                         workers: int = 1, progress: Callable[[int, int], None] | None = None) -> BootstrapCovariance:
    """Parametric bootstrap of the calibration ``cal`` (module docstring).

    Parameters
    ----------
    cal : StereoCalibration
        The calibration of ``points_left``/``points_right`` (its model and lens are reused).
    points_left, points_right : ndarray, shape (V, N, 2), px
        The corners it was calibrated from (missing corners NaN rows): where they were found.
    board_mm : ndarray, shape (N, 3), mm
    image_size : (width, height), px
    draws : int
        Number of recalibrations K (>= :data:`MIN_DRAWS`).
    seed : int
        Draw k's noise comes from ``numpy.random.default_rng([seed, k])``.
    tilt_guess_left_deg, tilt_guess_right_deg, joint, image_size_right, solver
        The options ``cal`` was made with (:func:`~measurement.calibration.stepwise.calibrate_stereo`).
    workers : int
        Processes to spread the draws over (1: in this process).
    progress : callable (done, total), optional

    Returns
    -------
    BootstrapCovariance

    Raises
    ------
    CalibrationError
        When more than :data:`MAX_FAILED_FRACTION` of the draws (or all but one) are refused.
    """
    draws = int(draws)
    if draws < MIN_DRAWS:
        raise ValueError(f"draws must be at least {MIN_DRAWS}, got {draws}")
    if int(workers) < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    points_left, points_right = np.asarray(points_left, float), np.asarray(points_right, float)
    board_mm = np.asarray(board_mm, float)
    if points_left.shape != points_right.shape or points_left.shape[1:] != (len(board_mm), 2):
        raise ValueError(f"points_left {points_left.shape} and points_right {points_right.shape} must both be "
                         f"(views, {len(board_mm)}, 2)")
    if len(cal.left.rvecs) != len(points_left):
        raise ValueError(f"the calibration has {len(cal.left.rvecs)} board poses but the corners {len(points_left)} "
                         "views: give the corners it was calibrated from")
    names = _names(cal)
    sigma_px = residual_sigma_px(cal, points_left, points_right, board_mm)
    # the residual variance of the fit, per coordinate, both cameras pooled: the unit of a cost difference
    s2 = float(np.mean([sigma_px["left"] ** 2, sigma_px["right"] ** 2]))
    options = dict(image_size=tuple(image_size), tilt_guess_left_deg=tuple(tilt_guess_left_deg),
                   tilt_guess_right_deg=tuple(tilt_guess_right_deg), joint=joint,
                   image_size_right=None if image_size_right is None else tuple(image_size_right), solver=solver,
                   # each draw is also solved from this world's truth (the wrong-minimum check below), which is what
                   # the calibration's multi-start guard is for: one start per draw suffices, at a fifth of the cost
                   multi_start=False)
    jobs = [(cal, _found(points_left), _found(points_right), board_mm, sigma_px, int(seed), k, names, options, s2)
            for k in range(draws)]
    results = []
    if int(workers) == 1:
        for i, job in enumerate(jobs):
            results.append(_draw(job))
            if progress is not None:
                progress(i + 1, draws)
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: a forked child would inherit the parent's threads (numba, BLAS) in whatever state they were
        with ProcessPoolExecutor(int(workers), mp_context=multiprocessing.get_context("spawn")) as pool:
            for i, result in enumerate(pool.map(_draw, jobs)):
                results.append(result)
                if progress is not None:
                    progress(i + 1, draws)
    kept = [(x, ok, wrong) for x, ok, wrong in results if x is not None]
    failed = draws - len(kept)
    if len(kept) < MIN_DRAWS or failed > MAX_FAILED_FRACTION * draws:
        raise CalibrationError(f"the bootstrap's calibration refused {failed} of {draws} synthetic corner sets "
                               f"(more than {MAX_FAILED_FRACTION:.0%}): the calibration is too fragile at its own "
                               "noise level for a bootstrap covariance")
    wrong = sum(w for _, _, w in kept)
    if wrong:
        warnings.warn(f"the stepwise calibration stopped in a worse local minimum in {wrong} of {len(kept)} bootstrap "
                      "draws (the tilt/principal-point valley): at this corner noise it may miss the least-squares "
                      "solution of real data too; the covariance uses the better minima", UserWarning, stacklevel=2)
    theta = parameter_vector(cal, names)
    dev = np.array([x for x, _, _ in kept]) - theta
    cov = np.atleast_2d(np.cov(dev, rowvar=False, ddof=1))
    cov = 0.5 * (cov + cov.T)
    return BootstrapCovariance(cov, names, dev, sigma_px, len(kept), failed, sum(not ok for _, ok, _ in kept),
                               sum(wrong for _, _, wrong in kept), int(seed))


def with_bootstrap_covariance(cal: StereoCalibration, points_left: np.ndarray, points_right: np.ndarray,
                              board_mm: np.ndarray, image_size: tuple[int, int], *, draws: int = 40, seed: int = 0,
                              **options) -> tuple[StereoCalibration, BootstrapCovariance]:
    """``cal`` with its covariance replaced by the bootstrap's (:func:`bootstrap_covariance`, same arguments).

    The sigmas (``left.sigma``, ``right.sigma``, ``sigma_stereo``) are left as the linear ones: they describe the
    least-squares fit; the covariance (what is propagated to points) says which estimator made it in
    ``covariance_estimator``.

    Returns
    -------
    tuple
        ``(the calibration with the bootstrap covariance, the BootstrapCovariance)``.
    """
    boot = bootstrap_covariance(cal, points_left, points_right, board_mm, image_size, draws=draws, seed=seed,
                                **options)
    return replace(cal, covariance=boot.covariance, covariance_names=boot.names,
                   covariance_estimator=bootstrap_estimator(boot.draws)), boot
