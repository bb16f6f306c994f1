"""Step 1 of the paper's calibration: focal lengths and board poses from homographies (Zhang 2000).

The Scheimpflug tilt and the distortion are ignored here (as in the paper); the principal point is taken at
the image centre, so only fx, fy remain in Zhang's closed form.
"""
from __future__ import annotations

import cv2
import numpy as np


def homography(board_xy_mm: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Plane-to-image homography (3, 3) from board (x, y) to pixels by normalised DLT (OpenCV, no RANSAC)."""
    H, _ = cv2.findHomography(np.asarray(board_xy_mm, float), np.asarray(pixels, float), 0)
    if H is None:
        raise ValueError("homography estimation failed (degenerate corner layout)")
    return H


def focal_lengths_from_homographies(homographies: list[np.ndarray], cx: float, cy: float) -> tuple[float, float]:
    """Zhang's closed form for (fx, fy) with a known principal point and zero skew.

    With ``H' = T H`` (T moves the principal point to the origin) and ``B = diag(1/fx^2, 1/fy^2, 1)``, each view
    gives ``h1' B h2 = 0`` and ``h1' B h1 = h2' B h2``: linear in (1/fx^2, 1/fy^2). Needs views that are not all
    fronto-parallel; raises ``ValueError`` when the system is degenerate.
    """
    T = np.array([[1.0, 0.0, -cx], [0.0, 1.0, -cy], [0.0, 0.0, 1.0]])
    rows, rhs = [], []
    for H in homographies:
        Hn = T @ H
        Hn = Hn / np.linalg.norm(Hn[:, 0])
        h1, h2 = Hn[:, 0], Hn[:, 1]
        rows.append([h1[0] * h2[0], h1[1] * h2[1]])
        rhs.append(-h1[2] * h2[2])
        rows.append([h1[0] ** 2 - h2[0] ** 2, h1[1] ** 2 - h2[1] ** 2])
        rhs.append(-(h1[2] ** 2 - h2[2] ** 2))
    A, b = np.array(rows), np.array(rhs)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    if np.linalg.cond(A) > 1e8 or np.any(sol <= 0):
        raise ValueError("cannot initialise the focal length: the board views are (nearly) fronto-parallel or too "
                         "few; tilt the board by 20-45 degrees in several directions")
    return float(1.0 / np.sqrt(sol[0])), float(1.0 / np.sqrt(sol[1]))


def pose_from_homography(H: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Board pose ``X_cam = R X_board + t`` from a homography and K: returns (rvec (3,), t (3,) mm)."""
    M = np.linalg.inv(K) @ H
    lam = 1.0 / np.linalg.norm(M[:, 0])
    if M[2, 2] * lam < 0:
        lam = -lam        # the board must be in front of the camera
    r1, r2, t = lam * M[:, 0], lam * M[:, 1], lam * M[:, 2]
    R = np.stack([r1, r2, np.cross(r1, r2)], axis=1)
    U, _, Vt = np.linalg.svd(R)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return cv2.Rodrigues(R)[0].ravel(), t
