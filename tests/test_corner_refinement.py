"""Saddle-fit corner refinement on a synthetic, exactly known checkerboard image."""
import numpy as np
from scipy.ndimage import gaussian_filter

from measurement.calibration.detection import refine_corners_saddle


def _affine_board(seed=0, square_px=30.0, noise_grey=1.0, blur_px=0.7):
    """4 x 4 squares under an affine map (shear, rotation, anisotropic scale); corners known exactly."""
    A = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]]) @ np.array([[1.0, 0.15], [0.0, 0.8]])
    A *= square_px
    origin = np.array([60.3, 48.7])
    n = 8  # supersampling per pixel axis
    H = W = 180
    ys, xs = np.mgrid[0:H * n, 0:W * n]
    pts = np.stack([(xs + 0.5) / n - 0.5, (ys + 0.5) / n - 0.5], -1) - origin
    board = pts @ np.linalg.inv(A).T          # board coordinates in squares; inner corners at integers 0..2
    col, row = np.floor(board[..., 0]), np.floor(board[..., 1])
    inside = (board[..., 0] >= -1) & (board[..., 0] < 3) & (board[..., 1] >= -1) & (board[..., 1] < 3)
    value = np.where(inside, np.where((col + row) % 2 == 0, 30.0, 220.0), 220.0)
    image = value.reshape(H, n, W, n).mean(axis=(1, 3))
    image = gaussian_filter(image, blur_px) + np.random.default_rng(seed).normal(0, noise_grey, image.shape)
    jj, ii = np.meshgrid(np.arange(3), np.arange(3))
    corners = np.stack([jj.ravel(), ii.ravel()], 1) @ A.T + origin
    return image, corners


def test_refinement_recovers_known_corners():
    image, truth = _affine_board()
    start = truth + np.random.default_rng(1).normal(0, 0.3, truth.shape)
    refined = refine_corners_saddle(image, start, pattern_size=(3, 3))
    err = np.linalg.norm(refined - truth, axis=1)
    # 1 grey level of noise on a 190-grey step, ~10 px window: the fit's noise is a few thousandths of a pixel.
    assert err.max() < 0.02, err
    assert np.linalg.norm(start - truth, axis=1).mean() > 10 * err.mean()


def test_refinement_keeps_corners_it_cannot_fit():
    image, truth = _affine_board()
    flat = np.full_like(image, 128.0)
    refined = refine_corners_saddle(flat, truth, pattern_size=(3, 3))
    assert np.all(np.linalg.norm(refined - truth, axis=1) <= 1.0)   # never runs away
