"""The paper's stepwise Scheimpflug stereo calibration (§2.2), with Levenberg-Marquardt-type least squares.

Per camera:
  step 1  alpha, beta from a datasheet guess, principal point at the image centre, no distortion; fx, fy and
          the board poses from homographies (Zhang, :mod:`measurement.calibration.zhang`);
  step 2  refine {fx, fy, alpha, beta, poses};
  step 3  refine {fx, fy, cx, cy, poses};
  step 4  refine {fx, fy, k1, k2, p1, p2, poses};
  final   (``refine_all``, default) all of the model's intrinsics and the poses together (steps 2-4 alone stop
          ~0.3 px short of the least-squares solution with Table 1's distortion, see :func:`calibrate_camera`);
then for the pair:
  step 5  the right camera's pose relative to the left, initialised from every view by eq (11) (written here
          for ``X_right = R X_left + T``: ``R = R_r R_l^T``, ``T = t_r - R t_l``) and refined with the left board
          poses over both cameras' corners (eq 12), intrinsics fixed;
  joint   (optional) all intrinsics of both cameras, the stereo pose and the board poses together.

Solver: Levenberg-Marquardt on a block finite-difference Jacobian. Each view's residuals depend only on the
intrinsics (and the stereo pose) and that view's six pose parameters, so a whole Jacobian costs
2 (n_shared + 6) residual evaluations, and the normal equations have the bundle-adjustment structure.
``solver="schur-lm"`` (default, :mod:`measurement.calibration.lm`) eliminates the 6 x 6 pose blocks by Schur
complement and solves only the reduced system of the ~10-26 shared parameters per step; ``solver="minpack-lm"``
is ``scipy.optimize.least_squares(method="lm")`` (MINPACK) on the same Jacobian stored dense. Both minimise the
same cost and reach the same minimum (``tests/test_calibration.py`` checks it); MINPACK's dense QR of the
(2-4 N V) x (n_shared + 6 V) Jacobian, ~80 % of the time at 30 views, is what the structured solver avoids.
scipy's sparse alternative (``method="trf"`` with LSMR subproblems) stopped short of the minimum on the
near-degenerate tilt/principal-point directions unless its inner tolerances were tuned, hence a direct solver.
Parameter uncertainties are ``sqrt(diag(s^2 (J^T J)^-1))`` with ``s^2`` the residual variance, at the final
solution, from the full (dense, n_shared + 6 V square) normal matrix.

Models: ``rmm`` (the paper), ``opencv-tilt`` (OpenCV's tau_x, tau_y order of rotations), ``pinhole``
(conventional: no tilt, alpha = beta = 0 fixed).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from measurement.calibration.lm import block_fd_jacobian, levenberg_marquardt
from measurement.calibration.zhang import focal_lengths_from_homographies, homography, pose_from_homography
from measurement.camera import INTRINSIC_NAMES, ScheimpflugCamera

MODELS = ("rmm", "opencv-tilt", "pinhole")
_TILT_MODEL = {"rmm": "rmm", "opencv-tilt": "opencv", "pinhole": "rmm"}
#: Least-squares solvers (module docstring): structured LM with Schur complement, or scipy's MINPACK LM.
SOLVERS = ("schur-lm", "minpack-lm")

#: Steps 2-4 of §2.2: the intrinsics each one frees (the poses are always free).
STEPS = (("step 2", ("fx", "fy", "alpha_deg", "beta_deg")),
         ("step 3", ("fx", "fy", "cx", "cy")),
         ("step 4", ("fx", "fy", "k1", "k2", "p1", "p2")))


class CalibrationError(ValueError):
    """The data cannot support a calibration (too few views, degenerate poses...)."""


@dataclass
class CameraCalibration:
    """Result of the single-camera steps 1-4.

    Attributes
    ----------
    camera : calibrated intrinsics
    rvecs, tvecs_mm : (V, 3) board poses ``X_cam = R(rvec) X_board + t``
    rms_px : reprojection RMS over all corners (per coordinate pair: sqrt(mean(du^2 + dv^2)))
    per_view_rms_px : (V,)
    sigma : standard uncertainty of every intrinsic parameter (same names)
    steps : [(name, free parameters, rms_px)] in the order run
    """

    camera: ScheimpflugCamera
    rvecs: np.ndarray
    tvecs_mm: np.ndarray
    rms_px: float
    per_view_rms_px: np.ndarray
    sigma: dict
    steps: list = field(default_factory=list)


@dataclass
class StereoCalibration:
    """Result of the whole procedure for a stereo pair; ``X_right = R_right_from_left X_left + T``."""

    model: str
    left: CameraCalibration
    right: CameraCalibration
    R_right_from_left: np.ndarray
    T_right_from_left_mm: np.ndarray
    sigma_stereo: dict
    rms_px: dict
    per_view_rms_px: dict
    steps: list = field(default_factory=list)


# ------------------------------------------------------------------------------------------------------------
def project_views(camera: ScheimpflugCamera, rvecs: np.ndarray, tvecs_mm: np.ndarray, board_mm: np.ndarray) -> np.ndarray:
    """Project board points for every pose: (V, 3), (V, 3), (N, 3) -> (V, N, 2) px."""
    R = Rotation.from_rotvec(np.asarray(rvecs).reshape(-1, 3)).as_matrix()
    # Batched matmul, not einsum: this runs thousands of times per calibration (finite differences).
    X = board_mm @ R.transpose(0, 2, 1) + np.asarray(tvecs_mm).reshape(-1, 1, 3)
    return camera.project(X.reshape(-1, 3)).reshape(len(R), len(board_mm), 2)


def _with(camera: ScheimpflugCamera, names, values) -> ScheimpflugCamera:
    return replace(camera, **{n: float(v) for n, v in zip(names, values)})


def _uncertainty(normal: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """Standard uncertainties ``sqrt(diag(s^2 (J^T J)^-1))`` from the normal matrix ``J^T J`` (n, n) -> (n,)."""
    n = len(normal)
    dof = max(1, len(residuals) - n)
    s2 = float(residuals @ residuals) / dof
    try:
        cov = s2 * np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return np.full(n, np.nan)
    return np.sqrt(np.clip(np.diag(cov), 0, None))


def _rms(residual_uv: np.ndarray) -> float:
    """RMS reprojection error of (..., 2) residuals: sqrt(mean(du^2 + dv^2))."""
    return float(np.sqrt(np.mean(np.sum(residual_uv ** 2, axis=-1))))


def _check_views(image_points: np.ndarray, board_mm: np.ndarray, minimum: int, what: str) -> None:
    if image_points.ndim != 3 or image_points.shape[2] != 2 or image_points.shape[1] != len(board_mm):
        raise CalibrationError(f"{what}: expected image points of shape (views, {len(board_mm)}, 2), "
                               f"got {image_points.shape}")
    if len(image_points) < minimum:
        raise CalibrationError(f"{what}: {len(image_points)} usable views, the model needs at least {minimum}")
    if not np.all(np.isfinite(image_points)):
        raise CalibrationError(f"{what}: image points contain NaN or inf")


# ------------------------------------------------------------------------------------------------------------
def _mono_residual_fn(camera, free, board_mm, image_points):
    """Residual of one camera; x = [free intrinsics..., (rvec, t) of each view]."""
    V, k = len(image_points), len(free)

    def residual(x):
        cam = _with(camera, free, x[:k])
        poses = x[k:].reshape(V, 6)
        return (project_views(cam, poses[:, :3], poses[:, 3:], board_mm) - image_points).ravel()

    return residual


def _refine_camera(camera, free, rvecs, tvecs, board_mm, image_points, solver):
    """Least squares over the ``free`` intrinsics and all poses; returns (camera, rvecs, tvecs, result)."""
    V, N = image_points.shape[:2]
    x0 = np.concatenate([[getattr(camera, n) for n in free], np.hstack([rvecs, tvecs]).ravel()])
    k = len(free)
    res = _solve(_mono_residual_fn(camera, free, board_mm, image_points), x0, k, _mono_rows(V, N), solver)
    cam = _with(camera, free, res.x[:k])
    poses = res.x[k:].reshape(V, 6)
    return cam, poses[:, :3].copy(), poses[:, 3:].copy(), res


def calibrate_camera(image_points: np.ndarray, board_mm: np.ndarray, image_size: tuple[int, int], *,
                     model: str = "rmm", tilt_guess_deg: tuple[float, float] = (0.0, 0.0),
                     name: str = "camera", refine_all: bool = True, solver: str = "schur-lm") -> CameraCalibration:
    """Steps 1-4 of §2.2 for one camera (then, by default, all intrinsics refined together).

    Parameters
    ----------
    image_points : (V, N, 2) detected corners per view, px
    board_mm : (N, 3) the same corners on the board, mm (z = 0)
    image_size : (width, height) px
    model : ``rmm``, ``opencv-tilt`` or ``pinhole``
    tilt_guess_deg : datasheet (alpha, beta) for step 1 (ignored by ``pinhole``)
    refine_all : after step 4, refine all of the model's intrinsics and the poses together (step "final").
        Steps 2-4 never free the tilt, the principal point and the distortion at the same time: step 2's tilt
        absorbs the (still unmodelled) distortion, step 3 then finds a zero gradient in (cx, cy) (a shift of
        the principal point is nearly a change of tilt), and step 4 cannot undo either. With Table 1's
        distortion that leaves ~0.3 px RMS on exact data, and ``sigma`` would not describe a least-squares
        solution. ``False`` gives the paper's steps 1-4 alone.
    solver : ``schur-lm`` (default) or ``minpack-lm``, see the module docstring (same minimum)
    """
    if model not in MODELS:
        raise CalibrationError(f"unknown camera model {model!r}; choose one of {', '.join(MODELS)}")
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {', '.join(SOLVERS)}")
    image_points = np.asarray(image_points, float)
    board_mm = np.asarray(board_mm, float)
    _check_views(image_points, board_mm, 3, name)
    width, height = image_size
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    Hs = [homography(board_mm[:, :2], p) for p in image_points]
    try:
        fx, fy = focal_lengths_from_homographies(Hs, cx, cy)
    except ValueError as err:
        raise CalibrationError(f"{name}: {err}") from None
    alpha, beta = (0.0, 0.0) if model == "pinhole" else tilt_guess_deg
    camera = ScheimpflugCamera(fx=fx, fy=fy, cx=cx, cy=cy, alpha_deg=alpha, beta_deg=beta, width=width,
                               height=height, tilt_model=_TILT_MODEL[model])
    K = camera.K
    poses = [pose_from_homography(H, K) for H in Hs]
    rvecs = np.array([p[0] for p in poses])
    tvecs = np.array([p[1] for p in poses])
    steps = [("step 1", ("fx", "fy", "poses from homographies"),
              _rms(project_views(camera, rvecs, tvecs, board_mm) - image_points))]
    for step_name, free in STEPS:
        if model == "pinhole":
            free = tuple(n for n in free if n not in ("alpha_deg", "beta_deg"))
        camera, rvecs, tvecs, _ = _refine_camera(camera, free, rvecs, tvecs, board_mm, image_points, solver)
        steps.append((step_name, free, _rms(project_views(camera, rvecs, tvecs, board_mm) - image_points)))
    if refine_all:
        free = _free_intrinsics(model)
        camera, rvecs, tvecs, _ = _refine_camera(camera, free, rvecs, tvecs, board_mm, image_points, solver)
        steps.append(("final", free, _rms(project_views(camera, rvecs, tvecs, board_mm) - image_points)))
    return _finish_camera(camera, rvecs, tvecs, board_mm, image_points, model, steps)


def _free_intrinsics(model: str) -> tuple[str, ...]:
    return tuple(n for n in INTRINSIC_NAMES if not (model == "pinhole" and n in ("alpha_deg", "beta_deg")))


def _finish_camera(camera, rvecs, tvecs, board_mm, image_points, model, steps) -> CameraCalibration:
    """Residual statistics and parameter uncertainties (Jacobian over all intrinsics and poses)."""
    free = _free_intrinsics(model)
    V, N = image_points.shape[:2]
    x = np.concatenate([[getattr(camera, n) for n in free], np.hstack([rvecs, tvecs]).ravel()])
    k = len(free)
    residual = _mono_residual_fn(camera, free, board_mm, image_points)
    jac = block_fd_jacobian(residual, x, k, _mono_rows(V, N))
    r = jac.residual
    sig = _uncertainty(jac.normal_matrix(), r)
    sigma = {n: float(s) for n, s in zip(free, sig[:k])}
    for n in INTRINSIC_NAMES:
        sigma.setdefault(n, 0.0)          # held fixed by the model
    res_uv = r.reshape(V, N, 2)
    per_view = np.sqrt(np.mean(np.sum(res_uv ** 2, axis=-1), axis=1))
    return CameraCalibration(camera, rvecs, tvecs, _rms(res_uv), per_view, sigma, steps)


def _mono_rows(n_views, n_points):
    """Residual rows of each view for one camera, (V, 2 N): view v's corners, (u, v) interleaved."""
    return np.arange(n_views * 2 * n_points).reshape(n_views, 2 * n_points)


def _stereo_rows(n_views, n_points):
    """Residual rows of each view for a stereo pair, (V, 4 N): its left rows, then its right rows."""
    half = n_views * 2 * n_points
    rows = _mono_rows(n_views, n_points)
    return np.concatenate([rows, half + rows], axis=1)


def _solve(residual, x0, n_shared, view_rows, solver):
    """Levenberg-Marquardt with the block finite-difference Jacobian; returns an object with ``x``.

    ``schur-lm``: :func:`measurement.calibration.lm.levenberg_marquardt` with tolerances 1e-12: two decades
    tighter than the MINPACK call below, so that where it stops matters less; a solve costs ~5-50 Jacobians
    either way. ``minpack-lm``: scipy's MINPACK LM on the dense Jacobian (the solver before the structured
    one). A point at or behind a camera projects to NaN: it gets a huge residual, so both reject the step.
    """
    fn = lambda x: np.nan_to_num(residual(x), nan=1e6)  # noqa: E731

    def jacobian(x):
        return block_fd_jacobian(fn, x, n_shared, view_rows)

    if solver == "schur-lm":
        res = levenberg_marquardt(fn, jacobian, x0, ftol=1e-12, xtol=1e-12, gtol=1e-12, max_iter=400)
        converged, why = res.success, res.status
    else:
        res = least_squares(fn, x0, jac=lambda x: jacobian(x).dense(), method="lm", xtol=1e-10, ftol=1e-10,
                            gtol=1e-10, x_scale="jac", max_nfev=400)
        converged, why = res.status > 0, res.message
    if not converged:
        warnings.warn(f"calibration least squares ({solver}) did not converge: {why}", stacklevel=3)
    return res


# ------------------------------------------------------------------------------------------------------------
def _stereo_residual_fn(left, right, board_mm, pts_l, pts_r, shared_names):
    """Residual over both cameras; x = [left intrinsics..., right intrinsics..., stereo rvec, T, left poses]."""
    V = len(pts_l)
    nl = len(shared_names[0])
    nr = len(shared_names[1])

    def residual(x):
        cl = _with(left, shared_names[0], x[:nl])
        cr = _with(right, shared_names[1], x[nl:nl + nr])
        s = x[nl + nr:nl + nr + 6]
        poses = x[nl + nr + 6:].reshape(V, 6)
        Rs = Rotation.from_rotvec(s[:3]).as_matrix()
        Rl = Rotation.from_rotvec(poses[:, :3]).as_matrix()
        rr = Rotation.from_matrix(np.einsum("ij,vjk->vik", Rs, Rl)).as_rotvec()
        tr = poses[:, 3:] @ Rs.T + s[3:]
        el = project_views(cl, poses[:, :3], poses[:, 3:], board_mm) - pts_l
        er = project_views(cr, rr, tr, board_mm) - pts_r
        return np.concatenate([el.ravel(), er.ravel()])

    return residual


def _stereo_init(cal_l: CameraCalibration, cal_r: CameraCalibration) -> tuple[np.ndarray, np.ndarray]:
    """Eq (11) for every view, combined: chordal mean of the rotations, median of the translations."""
    Rl = Rotation.from_rotvec(cal_l.rvecs).as_matrix()
    Rr = Rotation.from_rotvec(cal_r.rvecs).as_matrix()
    Rs = np.einsum("vij,vkj->vik", Rr, Rl)                       # R_r R_l^T
    Ts = cal_r.tvecs_mm - np.einsum("vij,vj->vi", Rs, cal_l.tvecs_mm)
    R_mean = Rotation.from_matrix(Rs).mean().as_matrix()
    return R_mean, np.median(Ts, axis=0)


def calibrate_stereo(points_left: np.ndarray, points_right: np.ndarray, board_mm: np.ndarray,
                     image_size: tuple[int, int], *, model: str = "rmm",
                     tilt_guess_left_deg: tuple[float, float] = (0.0, 0.0),
                     tilt_guess_right_deg: tuple[float, float] = (0.0, 0.0), joint: bool = True,
                     image_size_right: tuple[int, int] | None = None,
                     solver: str = "schur-lm") -> StereoCalibration:
    """Steps 1-5 of §2.2 (and the optional joint refinement) for a stereo pair.

    ``points_left``/``points_right``: (V, N, 2) corners of the same V board poses seen by each camera.
    ``solver``: ``schur-lm`` (default) or ``minpack-lm``, see the module docstring (same minimum).
    """
    points_left = np.asarray(points_left, float)
    points_right = np.asarray(points_right, float)
    if points_left.shape != points_right.shape:
        raise CalibrationError(f"left and right corner arrays differ: {points_left.shape} vs {points_right.shape}")
    cal_l = calibrate_camera(points_left, board_mm, image_size, model=model, tilt_guess_deg=tilt_guess_left_deg,
                             name="left camera", solver=solver)
    cal_r = calibrate_camera(points_right, board_mm, image_size_right or image_size, model=model,
                             tilt_guess_deg=tilt_guess_right_deg, name="right camera", solver=solver)
    R0, T0 = _stereo_init(cal_l, cal_r)
    V, N = points_left.shape[:2]
    steps = [("left " + s[0], s[1], s[2]) for s in cal_l.steps] + [("right " + s[0], s[1], s[2]) for s in cal_r.steps]

    def solve(left, right, names, R, T, poses):
        fn = _stereo_residual_fn(left, right, board_mm, points_left, points_right, names)
        x0 = np.concatenate([[getattr(left, n) for n in names[0]], [getattr(right, n) for n in names[1]],
                             Rotation.from_matrix(R).as_rotvec(), T, poses.ravel()])
        k = len(names[0]) + len(names[1]) + 6
        res = _solve(fn, x0, k, _stereo_rows(V, N), solver)
        x = res.x
        nl = len(names[0])
        left = _with(left, names[0], x[:nl])
        right = _with(right, names[1], x[nl:k - 6])
        return left, right, Rotation.from_rotvec(x[k - 6:k - 3]).as_matrix(), x[k - 3:k], x[k:].reshape(V, 6), fn, x, k

    poses0 = np.hstack([cal_l.rvecs, cal_l.tvecs_mm])
    left, right, R, T, poses, fn, x, k = solve(cal_l.camera, cal_r.camera, ((), ()), R0, T0, poses0)
    r = fn(x)
    steps.append(("step 5", ("stereo R, T", "left poses"), _rms(r.reshape(-1, 2))))
    if joint:
        names = (_free_intrinsics(model), _free_intrinsics(model))
        left, right, R, T, poses, fn, x, k = solve(left, right, names, R, T, poses)
        r = fn(x)
        steps.append(("joint", ("all intrinsics", "stereo R, T", "left poses"), _rms(r.reshape(-1, 2))))
    # Uncertainties of everything at the solution (all intrinsics of both cameras free).
    names = (_free_intrinsics(model), _free_intrinsics(model))
    fn = _stereo_residual_fn(left, right, board_mm, points_left, points_right, names)
    x = np.concatenate([[getattr(left, n) for n in names[0]], [getattr(right, n) for n in names[1]],
                        Rotation.from_matrix(R).as_rotvec(), T, poses.ravel()])
    k = len(names[0]) + len(names[1]) + 6
    jac = block_fd_jacobian(fn, x, k, _stereo_rows(V, N))
    r = jac.residual
    sig = _uncertainty(jac.normal_matrix(), r)
    nl = len(names[0])
    sig_l = {n: float(s) for n, s in zip(names[0], sig[:nl])}
    sig_r = {n: float(s) for n, s in zip(names[1], sig[nl:k - 6])}
    for d in (sig_l, sig_r):
        for n in INTRINSIC_NAMES:
            d.setdefault(n, 0.0)
    sigma_stereo = {"rvec": sig[k - 6:k - 3].tolist(), "T_mm": sig[k - 3:k].tolist()}
    half = len(r) // 2
    el, er = r[:half].reshape(V, N, 2), r[half:].reshape(V, N, 2)
    Rl = Rotation.from_rotvec(poses[:, :3]).as_matrix()
    rr = Rotation.from_matrix(np.einsum("ij,vjk->vik", R, Rl)).as_rotvec()
    tr = poses[:, 3:] @ R.T + T
    out_l = CameraCalibration(left, poses[:, :3], poses[:, 3:], _rms(el),
                              np.sqrt(np.mean(np.sum(el ** 2, -1), 1)), sig_l, cal_l.steps)
    out_r = CameraCalibration(right, rr, tr, _rms(er), np.sqrt(np.mean(np.sum(er ** 2, -1), 1)), sig_r, cal_r.steps)
    if out_l.rms_px > 1.0 or out_r.rms_px > 1.0:
        warnings.warn(f"large reprojection error after calibration: left {out_l.rms_px:.3f} px, right "
                      f"{out_r.rms_px:.3f} px (wrong corner order, wrong square size or a bad view?)", stacklevel=2)
    return StereoCalibration(model, out_l, out_r, R, np.asarray(T, float), sigma_stereo,
                             {"left": out_l.rms_px, "right": out_r.rms_px},
                             {"left": out_l.per_view_rms_px, "right": out_r.per_view_rms_px}, steps)
