"""Render <-> model agreement: where does the renderer put a 3D point, compared with ``measurement.camera``?

No corner detector is involved (detectors carry their own ~0.015 px bias). For every inner corner of a
rendered checkerboard we build an *analytic* image of the pixels around it from the model's geometry: each
pixel is supersampled, every sub-pixel position is back-projected with :class:`ScheimpflugCamera`,
intersected with the known board plane and coloured by the printed pattern. The rendered patch is then
aligned to that analytic image by least squares over a sub-pixel shift ``s``, a gain and an offset:

    rendered(x) ~ gain * analytic(x + s) + offset

The rendered corner therefore sits at ``model projection - s``; ``|s|`` is the disagreement in pixels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measurement.camera import ScheimpflugCamera


@dataclass
class CornerFits:
    """Result of aligning the analytic patches of N corners to a rendered image.

    Attributes
    ----------
    model_px : (N, 2) where the model projects each corner
    offset_px : (N, 2) rendered position minus model position
    gain, bias : (N,) photometric fit
    rms_residual_grey : (N,) RMS of the fit residual
    converged : (N,) bool
    """

    model_px: np.ndarray
    offset_px: np.ndarray
    gain: np.ndarray
    bias: np.ndarray
    rms_residual_grey: np.ndarray
    converged: np.ndarray

    @property
    def distance_px(self) -> np.ndarray:
        return np.linalg.norm(self.offset_px, axis=1)


def _analytic_patches(camera: ScheimpflugCamera, pattern, R_cam_from_board, t_cam_from_board_mm,
                      pixel_uv, subsamples_uv, shift_px):
    """Mean printed radiance over each pixel's footprint, by supersampling.

    pixel_uv : (N, P, 2) pixel centres; subsamples_uv : (P, S, 2) offsets in [-0.5, 0.5), drawn
    independently per pixel so that the sampling steps do not line up along edges; shift_px : (N, 2).
    Returns (N, P).
    """
    uv = pixel_uv[:, :, None, :] + subsamples_uv[None, :, :, :] + shift_px[:, None, None, :]
    xy = camera.backproject(uv.reshape(-1, 2))
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    # Ray/plane intersection in the board frame: X_board = R^T (lambda d - t), with z_board = 0.
    R = np.asarray(R_cam_from_board)
    d_board = rays @ R                       # R^T d for each ray
    o_board = -R.T @ np.asarray(t_cam_from_board_mm)
    lam = -o_board[2] / d_board[:, 2]
    x = o_board[0] + lam * d_board[:, 0]
    y = o_board[1] + lam * d_board[:, 1]
    return pattern(x, y).reshape(uv.shape[:3]).mean(axis=2)


def fit_corners(image: np.ndarray, camera: ScheimpflugCamera, pattern, R_cam_from_board, t_cam_from_board_mm,
                corners_board_mm, half_size_px: int = 8, supersample: int = 12, seed: int = 0,
                max_iter: int = 12, tol_px: float = 1e-3, image_origin_px=(0, 0)) -> CornerFits:
    """Align the analytic patch around each corner to ``image`` and return the sub-pixel offsets.

    Parameters
    ----------
    image : (H, W) rendered grey image (possibly a crop whose top-left pixel is ``image_origin_px``)
    pattern : callable ``(x_mm, y_mm) -> radiance`` of the printed board in its own frame
    corners_board_mm : (N, 3) corners in the board frame
    half_size_px : each patch is (2 h + 1)^2 pixels centred on the model projection; keep it below the
        projected square size so that a patch sees only the four squares around its corner
    supersample : n x n jittered sub-pixel samples per pixel for the analytic image
    tol_px : stop when no shift update exceeds this
    """
    R = np.asarray(R_cam_from_board, float)
    t = np.asarray(t_cam_from_board_mm, float)
    corners = np.atleast_2d(np.asarray(corners_board_mm, float))
    model_px = camera.project(corners @ R.T + t)
    if not np.all(np.isfinite(model_px)):
        raise ValueError("a corner does not project into the camera (behind it or outside the model's range)")
    h = half_size_px
    centre = np.round(model_px).astype(int)
    dj, di = np.meshgrid(np.arange(-h, h + 1), np.arange(-h, h + 1))
    cols = centre[:, 0:1] + dj.ravel()[None, :]
    rows = centre[:, 1:2] + di.ravel()[None, :]
    r_img, c_img = rows - int(image_origin_px[1]), cols - int(image_origin_px[0])
    outside = (r_img.min(1) < 0) | (c_img.min(1) < 0) | (r_img.max(1) >= image.shape[0]) | (c_img.max(1) >= image.shape[1])
    if np.any(outside):
        k = int(np.flatnonzero(outside)[0])
        raise ValueError(f"the patch of corner {k} at ({model_px[k, 0]:.1f}, {model_px[k, 1]:.1f}) px leaves the image")
    observed = image[r_img, c_img].astype(float)                       # (N, P)
    pixel_uv = np.stack([cols, rows], axis=-1).astype(float)          # (N, P, 2)
    rng = np.random.default_rng(seed)
    n = supersample
    strata = np.stack(np.meshgrid(np.arange(n), np.arange(n)), -1).reshape(-1, 2)
    # Stratified, jittered independently per pixel: a shared jitter would line the sampling steps up along
    # axis-aligned edges and make the fit move in quantised steps.
    grid = (strata[None] + rng.random((pixel_uv.shape[1], n * n, 2))) / n - 0.5
    N = len(corners)
    shift = np.zeros((N, 2))
    step = 0.05
    ex, ey = np.array([step, 0.0]), np.array([0.0, step])
    converged = np.zeros(N, bool)
    def evaluate(s, idx=slice(None)):
        return _analytic_patches(camera, pattern, R, t, pixel_uv[idx], grid, s[idx])

    # Lucas-Kanade with the analytic image's gradient taken once at the model position (central
    # differences): the shifts are hundredths of a pixel, so the Jacobian does not need updating.
    ax = (evaluate(shift + ex) - evaluate(shift - ex)) / (2 * step)
    ay = (evaluate(shift + ey) - evaluate(shift - ey)) / (2 * step)
    for _ in range(max_iter):
        active = np.flatnonzero(~converged)
        if len(active) == 0:
            break
        a0 = evaluate(shift, active)
        for i, k in enumerate(active):
            # Linear least squares for (gain, bias) at this shift, then a Gauss-Newton step on the shift.
            A = np.stack([a0[i], np.ones_like(a0[i])], axis=1)
            gain, bias = np.linalg.lstsq(A, observed[k], rcond=None)[0]
            residual = observed[k] - gain * a0[i] - bias
            J = np.stack([gain * ax[k], gain * ay[k], a0[i], np.ones_like(a0[i])], axis=1)
            delta = np.linalg.lstsq(J, residual, rcond=None)[0][:2]
            shift[k] += delta
            converged[k] = np.max(np.abs(delta)) < tol_px
    a0 = evaluate(shift)
    gains, biases, rms = np.zeros(N), np.zeros(N), np.zeros(N)
    for k in range(N):
        A = np.stack([a0[k], np.ones_like(a0[k])], axis=1)
        (gains[k], biases[k]) = np.linalg.lstsq(A, observed[k], rcond=None)[0]
        rms[k] = np.sqrt(np.mean((observed[k] - gains[k] * a0[k] - biases[k]) ** 2))
    # rendered(x) = analytic(x + s): the rendered feature sits at model - s.
    return CornerFits(model_px, -shift, gains, biases, rms, converged)


def detector_errors(image: np.ndarray, pattern_size: tuple[int, int], true_px: np.ndarray) -> np.ndarray | None:
    """OpenCV ``findChessboardCornersSB`` corners minus the true pixels (matched by nearest), (N, 2) or None."""
    import cv2

    img8 = np.clip(np.round(image), 0, 255).astype(np.uint8)
    found, corners = cv2.findChessboardCornersSB(img8, pattern_size, flags=cv2.CALIB_CB_ACCURACY)
    if not found:
        return None
    corners = corners.reshape(-1, 2).astype(float)
    d = np.linalg.norm(corners[:, None, :] - true_px[None, :, :], axis=2)
    return corners - true_px[np.argmin(d, axis=1)]


def fourier_shift_fit(reference: np.ndarray, moved: np.ndarray, border_px: int = 16) -> np.ndarray:
    """Translation (dx, dy) px with ``moved(x) = reference(x - (dx, dy))``, by a Fourier-shift least squares.

    Starts from plain phase correlation (skimage, upsampled) and refines by shifting ``reference`` with the
    Fourier shift theorem and minimising the difference to ``moved`` away from the wrapped border. Exact for
    band-limited images; used to check that rendered translations are rendered as exact image shifts.
    """
    from scipy.ndimage import fourier_shift
    from scipy.optimize import least_squares
    from skimage.registration import phase_cross_correlation

    reference = np.asarray(reference, float)
    moved = np.asarray(moved, float)
    if reference.shape != moved.shape:
        raise ValueError(f"images differ in shape: {reference.shape} vs {moved.shape}")
    start = phase_cross_correlation(moved, reference, upsample_factor=100)[0]
    spectrum = np.fft.fft2(reference)
    inner = np.s_[border_px:-border_px, border_px:-border_px]

    def residual(s):
        shifted = np.fft.ifft2(fourier_shift(spectrum, (s[1], s[0]))).real
        return (shifted[inner] - moved[inner]).ravel()

    return least_squares(residual, [start[1], start[0]], x_scale=0.1).x
