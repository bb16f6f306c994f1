"""Reference face elements (truth side): the 2-D Lagrange families a specimen's surface is made of -- ``triangle``
(3 nodes), ``triangle6``, ``quad`` (4), ``quad8`` (serendipity), ``quad9`` -- in meshio's (VTK) node order, their
shape functions, and compiled kernels that interpolate nodal values and their tangents over many faces at once.

:class:`scenes.specimens.surface_mesh.SurfaceMesh` is built from these; the volume cells the faces come from are
:mod:`scenes.deformation.fe_elements`.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["FaceElement", "FACE_ELEMENTS", "FACE_ALIASES", "monomials", "interpolate", "interpolate_derivatives"]

#: Face families: name -> (reference node coordinates (n, 2), monomial exponents (n, 2), domain, corners).
_TRI3 = np.array([[0, 0], [1, 0], [0, 1]], float)
_TRI6 = np.concatenate([_TRI3, [[0.5, 0], [0.5, 0.5], [0, 0.5]]])
_QUAD4 = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
_QUAD8 = np.concatenate([_QUAD4, [[0.5, 0], [1, 0.5], [0.5, 1], [0, 0.5]]])
_QUAD9 = np.concatenate([_QUAD8, [[0.5, 0.5]]])


def _exponents(max_each: int, max_total: int | None = None, serendipity: bool = False) -> np.ndarray:
    e = [(a, b) for b in range(max_each + 1) for a in range(max_each + 1)
         if (max_total is None or a + b <= max_total) and not (serendipity and a == 2 and b == 2)]
    return np.array(e, dtype=float)


@dataclass(frozen=True, eq=False)
class FaceElement:
    """A 2-D Lagrange reference face: ``N(s) = m(s) @ C`` with ``C = V^-1`` (each function 1 at its node)."""

    name: str
    nodes: np.ndarray          # (n, 2)
    exponents: np.ndarray      # (n, 2)
    kind: str                  # "triangle" or "square"
    n_corners: int

    @functools.cached_property
    def coefficients(self) -> np.ndarray:
        V = np.prod(self.nodes[:, None, :] ** self.exponents[None, :, :], axis=2)
        return np.linalg.inv(V)

    @property
    def order(self) -> int:
        return 1 if len(self.nodes) == self.n_corners else 2

    def shape(self, st: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shape functions (P, n) and their derivatives (P, n, 2) at reference points ``st`` (P, 2)."""
        st = np.asarray(st, dtype=float).reshape(-1, 2)
        e = self.exponents.astype(int)
        pw = np.stack([np.ones_like(st), st, st * st], axis=2)                  # (P, 2, 3): dim, power
        dpw = np.stack([np.zeros_like(st), np.ones_like(st), 2 * st], axis=2)
        f = [pw[:, d, e[:, d]] for d in range(2)]
        g = [dpw[:, d, e[:, d]] for d in range(2)]
        C = self.coefficients
        N = (f[0] * f[1]) @ C
        dN = np.stack([(g[0] * f[1]) @ C, (f[0] * g[1]) @ C], axis=2)
        return N, dN


@numba.njit(cache=True, inline="always")
def monomials(exponents, s, t, m, ms, mt):
    """The monomials ``s^a t^b`` of a face family at one point and their (s, t) derivatives (powers <= 2)."""
    for j in range(exponents.shape[0]):
        es, et = exponents[j, 0], exponents[j, 1]
        ps = 1.0 if es == 0 else (s if es == 1 else s * s)
        pt = 1.0 if et == 0 else (t if et == 1 else t * t)
        m[j] = ps * pt
        ms[j] = 0.0 if es == 0 else (pt if es == 1 else 2.0 * s * pt)
        mt[j] = 0.0 if et == 0 else (ps if et == 1 else 2.0 * t * ps)


@numba.njit(cache=True, parallel=True)
def interpolate(st, sel, conn, V, exponents, C, out):
    """``out[sel[i]] = sum_a N_a(st[sel[i]]) V[conn[i, a]]``, the shape functions ``N = m(s, t) @ C`` of
    :meth:`FaceElement.shape` formed per point (no (P, n) arrays)."""
    n, d = C.shape[0], V.shape[1]
    for i in numba.prange(len(sel)):
        p = sel[i]
        m, ms, mt = np.empty(n), np.empty(n), np.empty(n)
        monomials(exponents, st[p, 0], st[p, 1], m, ms, mt)
        for c in range(d):
            out[p, c] = 0.0
        for a in range(n):
            N = 0.0
            for j in range(n):
                N += m[j] * C[j, a]
            for c in range(d):
                out[p, c] += N * V[conn[i, a], c]


@numba.njit(cache=True, parallel=True)
def interpolate_derivatives(st, sel, conn, V, exponents, C, out):
    """``out[sel[i]] = sum_a dN_a/d(s, t) V[conn[i, a]]``, (M, d, 2), as :func:`_interpolate`."""
    n, d = C.shape[0], V.shape[1]
    for i in numba.prange(len(sel)):
        p = sel[i]
        m, ms, mt = np.empty(n), np.empty(n), np.empty(n)
        monomials(exponents, st[p, 0], st[p, 1], m, ms, mt)
        for c in range(d):
            out[p, c, 0] = 0.0
            out[p, c, 1] = 0.0
        for a in range(n):
            gs = 0.0
            gt = 0.0
            for j in range(n):
                gs += ms[j] * C[j, a]
                gt += mt[j] * C[j, a]
            for c in range(d):
                v = V[conn[i, a], c]
                out[p, c, 0] += gs * v
                out[p, c, 1] += gt * v


FACE_ELEMENTS = {f.name: f for f in [
    FaceElement("triangle", _TRI3, _exponents(1, 1), "triangle", 3),
    FaceElement("triangle6", _TRI6, _exponents(2, 2), "triangle", 3),
    FaceElement("quad", _QUAD4, _exponents(1), "square", 4),
    FaceElement("quad8", _QUAD8, _exponents(2, serendipity=True), "square", 4),
    FaceElement("quad9", _QUAD9, _exponents(2), "square", 4),
]}
#: meshio spellings of the same families.
FACE_ALIASES = {"triangle3": "triangle", "tri": "triangle", "quad4": "quad"}
