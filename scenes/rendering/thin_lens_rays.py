"""What a thin-lens pixel's quadrature needs of the lens and the paint, shared by the flat-face and the mesh paths
(:mod:`scenes.rendering.defocus_quadrature`, :mod:`scenes.rendering.defocus_mesh`): the conjugate in the plane of sharp focus of a
sensor corner, as the Mitsuba sensor plugin computes it, and Mitsuba's bilinear texture lookup."""
from __future__ import annotations

import numba


@numba.njit(cache=True, inline="always")
def focus_point(xy, r, c, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm):
    """The conjugate, in the plane of sharp focus, of sensor corner (r, c) (camera frame, mm), as the plugin
    computes it: along the undistorted chief ray at the depth conjugate to the corner's distance behind the lens."""
    s = (c - 0.5 - cx) / fx
    t = (r - 0.5 - cy) / fy
    pz = 1.0 + s * e1z + t * e2z
    z_o = 1.0 / (1.0 / F_mm - 1.0 / (v_mm * pz))
    return xy[r, c, 0] * z_o, xy[r, c, 1] * z_o, z_o


@numba.njit(cache=True, inline="always")
def bilinear_lookup(texture, rows, cols, x, y):
    """Mitsuba's bilinear lookup (texel centres at integers, clamp to the edge); ``rows, cols >= 2``."""
    x = min(max(x, 0.0), cols - 1.0)
    y = min(max(y, 0.0), rows - 1.0)
    i0 = min(int(x), cols - 2)
    j0 = min(int(y), rows - 2)
    fx = x - i0
    fy = y - j0
    top = texture[j0, i0] + fx * (texture[j0, i0 + 1] - texture[j0, i0])
    bottom = texture[j0 + 1, i0] + fx * (texture[j0 + 1, i0 + 1] - texture[j0 + 1, i0])
    return top + fy * (bottom - top)


__all__ = ["bilinear_lookup", "focus_point"]
