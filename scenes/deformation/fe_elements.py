"""Reference volume finite elements (truth side): node coordinates in VTK / meshio node order and their shape
functions, for every volume cell type a user's FE file may hold (tetra, tetra10, hexahedron, hexahedron20,
hexahedron27, wedge).

The beam's solver writes its nodes in this order (:mod:`scenes.deformation.beam_bending`), the catalog writes its
results with it (:mod:`scenes.specimens.catalog`), and the surface of a volume mesh is read from it
(:mod:`scenes.specimens.surface_mesh`).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["ReferenceElement", "REFERENCE_ELEMENTS", "ELEMENT_ALIASES", "EXODUS_REORDERED"]


@dataclass(frozen=True, eq=False)
class ReferenceElement:
    """A Lagrange-type reference element: node coordinates and the monomials spanning its shape functions.

    The shape functions are ``N(xi) = m(xi) @ C`` with ``C = V^-1``, ``V[i, k] = m_k(node_i)``: each is 1 at
    its node and 0 at the others, in exactly the polynomial space of the element, so any node order/space can
    be written down instead of hand-coding the functions.
    """

    name: str
    nodes: np.ndarray        # (nn, 3) reference coordinates, in the file's node order
    exponents: np.ndarray    # (nn, 3) monomial exponents
    kind: str                # "simplex", "cube" or "prism": the reference domain
    n_corners: int

    @functools.cached_property
    def coefficients(self) -> np.ndarray:
        V = np.prod(self.nodes[:, None, :] ** self.exponents[None, :, :], axis=2)
        return np.linalg.inv(V)

    def shape(self, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shape functions (P, nn) and their reference derivatives (P, nn, 3) at xi (P, 3)."""
        e = self.exponents.astype(int)
        P = len(xi)
        # Powers 0..2 of each coordinate and their derivatives, picked per monomial.
        pw = np.stack([np.ones_like(xi), xi, xi * xi], axis=2)                     # (P, 3, 3): dim, power
        dpw = np.stack([np.zeros_like(xi), np.ones_like(xi), 2 * xi], axis=2)
        f = [pw[:, d, e[:, d]] for d in range(3)]                                  # (P, nm) each
        g = [dpw[:, d, e[:, d]] for d in range(3)]
        m = f[0] * f[1] * f[2]
        dm = np.stack([g[0] * f[1] * f[2], f[0] * g[1] * f[2], f[0] * f[1] * g[2]], axis=1)   # (P, 3, nm)
        C = self.coefficients
        dN = (dm.reshape(3 * P, -1) @ C).reshape(P, 3, -1)
        return m @ C, np.swapaxes(dN, 1, 2)

    def violation(self, xi: np.ndarray) -> np.ndarray:
        """How far xi lies outside the reference domain (0 inside), (P,)."""
        neg = np.maximum(-xi, 0.0)
        if self.kind == "cube":
            return np.max(np.maximum(neg, xi - 1.0), axis=1)
        if self.kind == "simplex":
            return np.maximum(neg.max(axis=1), xi.sum(axis=1) - 1.0)
        return np.maximum.reduce([neg.max(axis=1), xi[:, 0] + xi[:, 1] - 1.0, xi[:, 2] - 1.0])

    @property
    def centre(self) -> np.ndarray:
        return self.nodes[: self.n_corners].mean(axis=0)


def _exps(max_each: int, max_total: int | None = None, extra=None) -> np.ndarray:
    e = [(a, b, c) for c in range(max_each + 1) for b in range(max_each + 1) for a in range(max_each + 1)
         if max_total is None or a + b + c <= max_total]
    return np.array(e if extra is None else [t for t in e if extra(t)], dtype=float)


_HEX8 = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
_HEX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
_HEX20 = np.concatenate([_HEX8, [(_HEX8[a] + _HEX8[b]) / 2 for a, b in _HEX_EDGES]])
# VTK_TRIQUADRATIC_HEXAHEDRON: mid-face nodes of the -x, +x, -y, +y, -z, +z faces, then the centre.
_HEX27 = np.concatenate([_HEX20, [[0, .5, .5], [1, .5, .5], [.5, 0, .5], [.5, 1, .5], [.5, .5, 0], [.5, .5, 1],
                                  [.5, .5, .5]]])
_TET4 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
_TET10 = np.concatenate([_TET4, [(_TET4[a] + _TET4[b]) / 2 for a, b in
                                 [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)]]])
_WEDGE6 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], float)


REFERENCE_ELEMENTS = {r.name: r for r in [
    ReferenceElement("tetra", _TET4, _exps(1, 1), "simplex", 4),
    ReferenceElement("tetra10", _TET10, _exps(2, 2), "simplex", 4),
    ReferenceElement("hexahedron", _HEX8, _exps(1), "cube", 8),
    # Serendipity space: the Q2 monomials with at most one exponent equal to 2 (20 of them).
    ReferenceElement("hexahedron20", _HEX20, _exps(2, extra=lambda t: sum(a == 2 for a in t) <= 1), "cube", 8),
    ReferenceElement("hexahedron27", _HEX27, _exps(2), "cube", 8),
    ReferenceElement("wedge", _WEDGE6, np.array([(a, b, c) for c in (0, 1) for a, b in ((0, 0), (1, 0), (0, 1))], float),
                "prism", 6),
]}
ELEMENT_ALIASES = {"tetra4": "tetra", "hexahedron8": "hexahedron"}
#: Cell types whose node order in Exodus II differs from VTK's for the same meshio name (meshio passes them on
#: unchanged), so they are refused from Exodus files.
EXODUS_REORDERED = {"hexahedron20", "hexahedron27"}
