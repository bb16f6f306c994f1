"""The surface of a specimen as curved finite-element faces: what is painted, rendered and given a truth.

A user's specimen arrives as a surface mesh (triangles) or as the outer surface of a volume FE mesh. Either
way it becomes a :class:`SurfaceMesh`: node coordinates (mm, specimen frame) and faces of the 2-D Lagrange
families ``triangle`` (3 nodes), ``triangle6``, ``quad`` (4), ``quad8`` (serendipity), ``quad9``, in meshio's
(VTK) node order, every face oriented with its normal out of the material. A face is its own isoparametric map
``X(s, t) = sum_a N_a(s, t) X_a`` over the reference triangle ``s, t >= 0, s + t <= 1`` or square
``[0, 1]^2``; the same shape functions carry the nodal displacements, so the surface of a quadratic FE mesh
stays curved and moves as the FE field does.

For rendering and ray casting each face is cut into ``n x n`` flat pieces (:meth:`SurfaceMesh.tessellate`):
``n`` is chosen so that the flat pieces stay within a stated distance of the curved face (their sagitta),
and vertices on shared edges are computed once, so a closed surface stays closed bit for bit (the exact
renderer then culls its back faces). Every tessellation vertex keeps its face and ``(s, t)``: a ray's hit
on a flat piece maps back to a material point ``(face, s, t)`` of the FE surface.

Surface strain needs only the face itself: with the reference tangents ``a_i = dX/ds_i`` and the deformed
ones ``b_i = dx/ds_i`` (``x = X + u``), the Green-Lagrange strain of the surface is
``E = (L^-T b^T b L^-1 - I) / 2`` in the orthonormal tangent basis ``Q = a L^-1`` (``a^T a = L^T L``): the
tangential part of the 3-D strain of the FE interpolant, which is what a stereo-DIC surface strain measures
(:meth:`SurfaceMesh.surface_strain`).
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, replace

import numpy as np

from scenes.deformation.fe_elements import REFERENCE_ELEMENTS
from scenes.specimens.face_elements import (FACE_ALIASES, FACE_ELEMENTS, FaceElement, interpolate,
                                            interpolate_derivatives)

#: Reversing a face's orientation: the node permutation of each family.
_FLIP = {"triangle": [0, 2, 1], "triangle6": [0, 2, 1, 5, 4, 3], "quad": [0, 3, 2, 1],
         "quad8": [0, 3, 2, 1, 7, 6, 5, 4], "quad9": [0, 3, 2, 1, 7, 6, 5, 4, 8]}
#: Corner faces of the volume cells (VTK corner order; orientation is fixed afterwards, outwards).
_VOLUME_FACES = {
    "tetra": [(0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3)],
    "hexahedron": [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)],
    "wedge": [(0, 1, 2), (3, 4, 5), (0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5)],
}
_VOLUME_BASE = {"tetra": "tetra", "tetra10": "tetra", "hexahedron": "hexahedron", "hexahedron20": "hexahedron",
                "hexahedron27": "hexahedron", "wedge": "wedge"}


class MeshError(ValueError):
    """A mesh that cannot be a specimen surface (the message names the source and the fault)."""


def _volume_face_nodes(cell_type: str) -> list[tuple[str, list[int]]]:
    """The faces of a volume cell type as (face family, local node indices in the face's VTK order)."""
    ref = REFERENCE_ELEMENTS[cell_type].nodes
    lookup = {tuple(np.round(p, 6)): i for i, p in enumerate(ref)}
    out = []
    for corners in _VOLUME_FACES[_VOLUME_BASE[cell_type]]:
        nodes = list(corners)
        n = len(corners)
        mids = [lookup.get(tuple(np.round(0.5 * (ref[corners[i]] + ref[corners[(i + 1) % n]]), 6)))
                for i in range(n)]
        centre = lookup.get(tuple(np.round(ref[list(corners)].mean(axis=0), 6)))
        if n == 3:
            family = "triangle6" if all(m is not None for m in mids) else "triangle"
        else:
            family = "quad" if any(m is None for m in mids) else ("quad9" if centre is not None else "quad8")
        if family != "triangle" and family != "quad":
            nodes += mids
        if family == "quad9":
            nodes.append(centre)
        out.append((family, nodes))
    return out


@dataclass(frozen=True)
class Tessellation:
    """Flat triangles approximating a :class:`SurfaceMesh` (one set of vertices shared by every state).

    Attributes
    ----------
    face : (V,) int, the surface face of each vertex
    st : (V, 2) float, its reference coordinates on that face
    triangles : (T, 3) int, counter-clockwise seen from outside (the emitting side)
    triangle_face : (T,) int, the surface face each triangle lies on
    triangle_st : (T, 3, 2) float, the reference coordinates of the triangle's corners on that face (a vertex on a
        shared edge may have been computed from the neighbouring face: these are on the triangle's own face)
    n : int, pieces per face edge
    max_sagitta_mm : float, the largest distance measured between the flat pieces and the curved faces
    """

    face: np.ndarray
    st: np.ndarray
    triangles: np.ndarray
    triangle_face: np.ndarray
    triangle_st: np.ndarray
    n: int
    max_sagitta_mm: float


class SurfaceMesh:
    """Curved faces on nodes: the specimen's surface in its reference state.

    Parameters
    ----------
    points_mm : (P, 3) float, node coordinates, specimen frame, mm
    faces : dict family -> (F, n) int node indices (:data:`FACE_ELEMENTS`), normals out of the material
    source : a name for messages (the file)
    parents : dict family -> (F, 2) int, optional: the volume cell (type index into ``parent_types``, row) each
        face bounds (None for a surface mesh)
    parent_types : the volume cell types ``parents`` index
    """

    def __init__(self, points_mm, faces: dict, source: str = "<mesh>", parents: dict | None = None,
                 parent_types: tuple = ()):
        self.source = str(source)
        P = np.asarray(points_mm, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or not len(P):
            raise MeshError(f"{self.source}: node coordinates must be (P, 3) with P > 0, got {P.shape}")
        if not np.all(np.isfinite(P)):
            raise MeshError(f"{self.source}: node coordinates must be finite")
        self.points_mm = P
        self.faces: dict[str, np.ndarray] = {}
        for name, conn in faces.items():
            el = FACE_ELEMENTS[FACE_ALIASES.get(name, name)]
            conn = np.asarray(conn, dtype=np.int64).reshape(-1, len(el.nodes))
            if len(conn) and (conn.min() < 0 or conn.max() >= len(P)):
                raise MeshError(f"{self.source}: {name} faces index nodes outside 0..{len(P) - 1}")
            if len(conn):
                self.faces[el.name] = conn
        if not self.faces:
            raise MeshError(f"{self.source}: the mesh has no faces")
        self.parents = parents
        self.parent_types = tuple(parent_types)
        # One flat list of faces: family index and row, for per-face arrays.
        self.families = list(self.faces)
        self.face_family = np.concatenate([np.full(len(c), k) for k, c in enumerate(self.faces.values())])
        self.face_row = np.concatenate([np.arange(len(c)) for c in self.faces.values()])
        self.points_mm.setflags(write=False)

    def __repr__(self):
        counts = ", ".join(f"{len(c)} {n}" for n, c in self.faces.items())
        return f"SurfaceMesh({self.source!r}: {len(self.points_mm)} nodes, {counts})"

    @property
    def n_faces(self) -> int:
        return len(self.face_family)

    @property
    def order(self) -> int:
        """2 when some face is quadratic, else 1."""
        return max(FACE_ELEMENTS[n].order for n in self.faces)

    def surface_nodes(self) -> np.ndarray:
        """Indices of the nodes the faces use (sorted)."""
        return np.unique(np.concatenate([c.ravel() for c in self.faces.values()]))

    # ---- construction
    @classmethod
    def from_volume_cells(cls, points_mm, cells: dict, source: str = "<mesh>") -> "SurfaceMesh":
        """The outer surface of a volume mesh: every cell face used by exactly one cell, oriented outwards.

        Raises :class:`MeshError` for a face shared by more than two cells (non-manifold) or no volume cell.
        """
        P = np.asarray(points_mm, dtype=float)
        keys, families, conns, parents = [], [], [], []
        types = [t for t in cells if t in _VOLUME_BASE and len(cells[t])]
        if not types:
            raise MeshError(f"{source}: no volume cells of a supported type ({', '.join(sorted(_VOLUME_BASE))})")
        for ti, cell_type in enumerate(types):
            conn = np.asarray(cells[cell_type], dtype=np.int64)
            n_corner = {"tetra": 4, "hexahedron": 8, "wedge": 6}[_VOLUME_BASE[cell_type]]
            centre = P[conn[:, :n_corner]].mean(axis=1)
            for family, local in _volume_face_nodes(cell_type):
                f = conn[:, local]
                el = FACE_ELEMENTS[family]
                outward = _outward(P, f, el, centre)
                f = np.where(outward[:, None], f, f[:, _FLIP[family]])
                corners = np.sort(f[:, :el.n_corners], axis=1)
                keys.append(corners if el.n_corners == 4 else np.column_stack([corners, np.full(len(f), -1)]))
                families.append(np.full(len(f), list(FACE_ELEMENTS).index(family)))
                conns.append((family, f))
                parents.append(np.column_stack([np.full(len(f), ti), np.arange(len(f))]))
        K = np.concatenate(keys)
        _, inverse, counts = np.unique(K, axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        if np.any(counts > 2):
            raise MeshError(f"{source}: {int(np.sum(counts > 2))} faces are shared by more than two cells "
                            f"(a non-manifold mesh)")
        boundary = counts[inverse] == 1
        faces: dict[str, list] = {}
        parent: dict[str, list] = {}
        start = 0
        for (family, f), par in zip(conns, parents):
            keep = boundary[start:start + len(f)]
            start += len(f)
            faces.setdefault(family, []).append(f[keep])
            parent.setdefault(family, []).append(par[keep])
        faces = {k: np.concatenate(v) for k, v in faces.items()}
        parent = {k: np.concatenate(v) for k, v in parent.items()}
        return cls(P, faces, source=source, parents=parent, parent_types=tuple(types))

    @classmethod
    def from_surface_cells(cls, points_mm, cells: dict, source: str = "<mesh>", *,
                           towards_mm=None) -> "SurfaceMesh":
        """A surface mesh given as faces: their orientation made consistent (trimesh, over the corner
        triangles), outwards for a closed surface; an open one is turned so that most of its area faces
        ``towards_mm`` (a point, e.g. the cameras; default: keep the majority orientation). A repair is
        warned."""
        import trimesh

        P = np.asarray(points_mm, dtype=float)
        faces = {FACE_ALIASES.get(k, k): np.asarray(v, dtype=np.int64) for k, v in cells.items()
                 if FACE_ALIASES.get(k, k) in FACE_ELEMENTS and len(v)}
        if not faces:
            raise MeshError(f"{source}: the mesh has no faces")
        corner_tris, owner = [], []
        for k, (family, f) in enumerate(faces.items()):
            # a quad as two triangles, so that every edge it shares with a neighbour is seen
            split = [f[:, :3]] if FACE_ELEMENTS[family].n_corners == 3 else [f[:, [0, 1, 2]], f[:, [0, 2, 3]]]
            for j, part in enumerate(split):
                corner_tris.append(part)
                owner.append(np.column_stack([np.full(len(f), k), np.arange(len(f)), np.full(len(f), j)]))
        T = np.concatenate(corner_tris)
        own = np.concatenate(owner)
        mesh = trimesh.Trimesh(vertices=P, faces=T, process=False, validate=False)
        before = T.copy()
        trimesh.repair.fix_winding(mesh)
        if mesh.is_watertight:
            trimesh.repair.fix_inversion(mesh)
        flipped = np.any(np.asarray(mesh.faces) != before, axis=1)
        if not mesh.is_watertight:
            normals = np.cross(P[mesh.faces[:, 1]] - P[mesh.faces[:, 0]], P[mesh.faces[:, 2]] - P[mesh.faces[:, 0]])
            if towards_mm is not None:
                c = P[mesh.faces].mean(axis=1)
                facing = np.einsum("ij,ij->i", normals, np.asarray(towards_mm, float) - c)
                if np.sum(np.abs(np.linalg.norm(normals, axis=1)) * np.sign(facing)) < 0:
                    flipped = ~flipped
        out = {}
        first = own[:, 2] == 0                          # a face turns as its first triangle did
        for k, (family, f) in enumerate(faces.items()):
            flip = flipped[first & (own[:, 0] == k)]
            out[family] = np.where(flip[:, None], f[:, _FLIP[family]], f)
        n_flipped = int(flipped[first].sum())
        if 0 < n_flipped < int(first.sum()):
            warnings.warn(f"{source}: {n_flipped} of {int(first.sum())} faces had normals inconsistent with their "
                          f"neighbours and were turned", stacklevel=2)
        return cls(P, out, source=source)

    def flipped(self) -> "SurfaceMesh":
        """The same faces with every normal reversed (an open surface turned to face the other side)."""
        return SurfaceMesh(self.points_mm, {k: v[:, _FLIP[k]] for k, v in self.faces.items()}, source=self.source,
                           parents=self.parents, parent_types=self.parent_types)

    def mean_normal(self) -> np.ndarray:
        """Area-weighted mean of the faces' normals (corner triangles; not normalised)."""
        total = np.zeros(3)
        for name, conn in self.faces.items():
            c = self.points_mm[conn[:, :FACE_ELEMENTS[name].n_corners]]
            if FACE_ELEMENTS[name].n_corners == 3:
                total += np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]).sum(axis=0) / 2
            else:
                total += np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1]).sum(axis=0) / 2
        return total

    # ---- evaluation on faces
    def _face_nodes(self, face: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Per family present among ``face`` (M,): (family index, positions in ``face``, node indices (m, n))."""
        out = []
        fam = self.face_family[face]
        for k, name in enumerate(self.families):
            sel = np.flatnonzero(fam == k)
            if len(sel):
                out.append((k, sel, self.faces[name][self.face_row[face[sel]]]))
        return out

    def inside_face(self, face, st, tol: float = 1e-9) -> np.ndarray:
        """(M,) bool: whether ``st`` lies in its face's reference domain (the triangle ``s, t >= 0, s + t <= 1`` or
        the square ``[0, 1]^2``), within ``tol``; False for NaN."""
        face = np.asarray(face, np.int64).reshape(-1)
        s, t = np.asarray(st, float).reshape(-1, 2).T
        square = np.array([FACE_ELEMENTS[name].kind == "square" for name in self.families])[self.face_family[face]]
        low = (s >= -tol) & (t >= -tol)
        return np.where(square, low & (s <= 1 + tol) & (t <= 1 + tol), low & (s + t <= 1 + tol))

    def evaluate(self, face, st, nodal_mm) -> np.ndarray:
        """``sum_a N_a(s, t) v_a`` of nodal vectors ``nodal_mm`` (P, 3) at points ``(face (M,), st (M, 2))``."""
        face = np.asarray(face, dtype=np.int64).reshape(-1)
        st = np.asarray(st, dtype=float).reshape(-1, 2)
        V = np.asarray(nodal_mm, dtype=float)
        out = np.empty((len(face), V.shape[1]))
        for k, sel, conn in self._face_nodes(face):
            el = FACE_ELEMENTS[self.families[k]]
            interpolate(st, sel, conn, V, el.exponents.astype(np.int64), el.coefficients, out)
        return out

    def tangents(self, face, st, nodal_mm) -> np.ndarray:
        """``d(sum N_a v_a)/d(s, t)`` at the points: (M, 3, 2)."""
        face = np.asarray(face, dtype=np.int64).reshape(-1)
        st = np.asarray(st, dtype=float).reshape(-1, 2)
        V = np.asarray(nodal_mm, dtype=float)
        out = np.empty((len(face), 3, 2))
        for k, sel, conn in self._face_nodes(face):
            el = FACE_ELEMENTS[self.families[k]]
            interpolate_derivatives(st, sel, conn, V, el.exponents.astype(np.int64), el.coefficients, out)
        return out

    def positions(self, face, st, displacement_mm=None) -> np.ndarray:
        """Material points ``(face, st)`` in the reference state, or moved by nodal ``displacement_mm`` (P, 3)."""
        X = self.evaluate(face, st, self.points_mm)
        return X if displacement_mm is None else X + self.evaluate(face, st, displacement_mm)

    def normals(self, face, st, displacement_mm=None) -> np.ndarray:
        """Unit outward normals (M, 3) at the points, reference or deformed state."""
        V = self.points_mm if displacement_mm is None else self.points_mm + np.asarray(displacement_mm, float)
        a = self.tangents(face, st, V)
        n = np.cross(a[:, :, 0], a[:, :, 1])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def surface_strain(self, face, st, displacement_mm, reference_displacement_mm=None
                       ) -> tuple[np.ndarray, np.ndarray]:
        """Green-Lagrange surface strain of the state ``displacement_mm`` relative to the state
        ``reference_displacement_mm`` (default: the undeformed mesh), at material points ``(face, st)``.

        Returns
        -------
        E : (M, 2, 2) strain in the orthonormal tangent basis Q of the reference state
        Q : (M, 3, 2) that basis ``Q = a L^-1`` (module docstring), specimen frame: ``Q[:, :, 0]`` is along the
            reference state's ``dX/ds``, ``Q[:, :, 1]`` completes it in the tangent plane
        """
        U0 = np.zeros_like(self.points_mm) if reference_displacement_mm is None else reference_displacement_mm
        a = self.tangents(face, st, self.points_mm + np.asarray(U0, float))
        b = self.tangents(face, st, self.points_mm + np.asarray(displacement_mm, float))
        G = np.einsum("nki,nkj->nij", a, a)
        C = np.einsum("nki,nkj->nij", b, b)
        L = np.transpose(np.linalg.cholesky(G), (0, 2, 1))
        L_inv = np.linalg.inv(L)
        E = 0.5 * (np.transpose(L_inv, (0, 2, 1)) @ C @ L_inv - np.eye(2))
        return E, a @ L_inv

    # ---- tessellation
    def sagitta_mm(self, n: int, displacement_mm=None, samples: int = 3) -> float:
        """Largest distance between the curved faces and the planes of their ``n x n`` flat pieces, sampled inside
        the pieces. Along the plane a piece and its face may differ in parametrisation only (a graded mesh on a
        flat face): that moves no surface point, and the paint and the truth follow positions, not parameters."""
        if self.order == 1 and set(self.faces) <= {"triangle"}:
            return 0.0
        tess = self.tessellate(n, check=False)
        V = self.points_mm if displacement_mm is None else self.points_mm + np.asarray(displacement_mm, float)
        # barycentric samples inside each piece (not only the vertices, which lie on the surface)
        g = np.array([(i, j) for i in range(samples + 1) for j in range(samples + 1 - i)], float) / samples
        bary = np.column_stack([1 - g.sum(1), g])
        bary = bary[(bary > 0).all(axis=1)] if samples >= 3 else bary
        tri_st = tess.triangle_st                                                  # (T, 3, 2)
        pts_st = np.einsum("kb,tbd->tkd", bary, tri_st).reshape(-1, 2)
        faces = np.repeat(tess.triangle_face, len(bary))
        curved = self.evaluate(faces, pts_st, V)
        corners = self.evaluate(np.repeat(tess.triangle_face, 3), tri_st.reshape(-1, 2), V).reshape(-1, 3, 3)
        flat = np.einsum("kb,tbi->tki", bary, corners).reshape(-1, 3)
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        off = np.einsum("ti,tki->tk", normal, (curved - flat).reshape(len(corners), len(bary), 3))
        return float(np.max(np.abs(off))) if off.size else 0.0

    def pieces_for_sagitta(self, tolerance_mm: float, displacement_mm=None, max_n: int = 32) -> int:
        """The smallest ``n`` (1, 2, 4, ... up to ``max_n``) whose flat pieces stay within ``tolerance_mm``; warns
        when even ``max_n`` does not."""
        if not (np.isfinite(tolerance_mm) and tolerance_mm > 0):
            raise ValueError(f"the sagitta tolerance must be positive, got {tolerance_mm!r} mm")
        n = 1
        while True:
            s = self.sagitta_mm(n, displacement_mm)
            if s <= tolerance_mm:
                return n
            if 2 * n > max_n:
                warnings.warn(f"{self.source}: the faces are still {s:.3g} mm from their flat pieces at {n} x {n} "
                              f"pieces per face (tolerance {tolerance_mm:.3g} mm); finer FE faces would render "
                              f"closer to the curved surface", stacklevel=2)
                return n
            n *= 2

    def tessellate(self, n: int = 1, check: bool = True) -> Tessellation:
        """``n x n`` flat pieces per face (a triangle: ``n^2`` triangles; a square: ``2 n^2``), see the module
        docstring. Vertices on an edge shared by two faces are made once (keyed by the edge's end nodes and
        the position along it), so the pieces of neighbouring faces meet exactly."""
        n = int(n)
        if n < 1:
            raise ValueError(f"pieces per face edge must be >= 1, got {n}")
        keys, faces_v, st_v = [], [], []
        tri_local, tri_face = [], []
        offset = 0
        face_index_base = 0
        for name, conn in self.faces.items():
            el = FACE_ELEMENTS[name]
            F = len(conn)
            grid, local_tris, edge_of = _reference_grid(el.kind, n)
            G = len(grid)
            corners = conn[:, :el.n_corners]
            # keys: ("node", id) for corners, (edge lo, hi, step from lo) on edges, ("face", f, g) inside
            k = np.zeros((F, G, 4), dtype=np.int64)
            for g, (kind, a, b, pos) in enumerate(edge_of):
                if kind == 0:                                   # corner a
                    k[:, g] = np.column_stack([np.zeros(F, np.int64), corners[:, a], np.full(F, -1), np.zeros(F)])
                elif kind == 1:                                 # on the edge from corner a to corner b, pos/n
                    na, nb = corners[:, a], corners[:, b]
                    lo_first = na < nb
                    lo, hi = np.minimum(na, nb), np.maximum(na, nb)
                    step = np.where(lo_first, pos, n - pos)
                    k[:, g] = np.column_stack([np.ones(F, np.int64), lo, hi, step])
                else:                                           # interior
                    k[:, g] = np.column_stack([np.full(F, 2), face_index_base + np.arange(F), np.full(F, g),
                                               np.zeros(F)])
            keys.append(k.reshape(-1, 4))
            faces_v.append(np.repeat(face_index_base + np.arange(F), G))
            st_v.append(np.tile(grid, (F, 1)))
            tri_local.append((local_tris[None] + offset + G * np.arange(F)[:, None, None]).reshape(-1, 3))
            tri_face.append(np.repeat(face_index_base + np.arange(F), len(local_tris)))
            offset += F * G
            face_index_base += F
        K = np.concatenate(keys)
        face_all = np.concatenate(faces_v)
        st_all = np.concatenate(st_v)
        _, first, inverse = np.unique(K, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        tris_raw = np.concatenate(tri_local)
        triangles = inverse[tris_raw]
        # the vertex of every unique key is made from the first face that has it
        order = np.argsort(first)                  # keep vertices in first-seen order: deterministic numbering
        remap = np.empty_like(order)
        remap[order] = np.arange(len(order))
        tess = Tessellation(face=face_all[first[order]], st=st_all[first[order]], triangles=remap[triangles],
                            triangle_face=np.concatenate(tri_face), triangle_st=st_all[tris_raw], n=n,
                            max_sagitta_mm=float("nan"))
        if check:
            tess = replace(tess, max_sagitta_mm=self.sagitta_mm(n))
        return tess

    def tessellation_positions(self, tess: Tessellation, displacement_mm=None) -> np.ndarray:
        """(V, 3) positions of the tessellation's vertices, reference or deformed state."""
        return self.positions(tess.face, tess.st, displacement_mm)


def _outward(P: np.ndarray, f: np.ndarray, el: FaceElement, cell_centre: np.ndarray) -> np.ndarray:
    """(F,) True where the faces ``f`` (node order as given) have their normal pointing away from the cell centre."""
    c = P[f[:, :el.n_corners]]
    centre = c.mean(axis=1)
    if el.n_corners == 3:
        nrm = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    else:
        nrm = np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1])
    return np.einsum("ij,ij->i", nrm, centre - cell_centre) > 0


@functools.lru_cache(maxsize=16)
def _reference_grid(kind: str, n: int):
    """Grid points of an ``n x n`` subdivision of the reference triangle or square, its triangles
    (counter-clockwise in (s, t), i.e. the face's own orientation) and what each point is:
    (0, corner, -, -), (1, corner a, corner b, steps from a) on an edge, (2, -, -, -) inside."""
    pts, where = [], []
    index = {}
    if kind == "triangle":
        for j in range(n + 1):
            for i in range(n + 1 - j):
                index[(i, j)] = len(pts)
                pts.append((i / n, j / n))
                where.append(_where_triangle(i, j, n))
        tris = []
        for j in range(n):
            for i in range(n - j):
                tris.append((index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]))
                if i + j < n - 1:
                    tris.append((index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]))
    else:
        for j in range(n + 1):
            for i in range(n + 1):
                index[(i, j)] = len(pts)
                pts.append((i / n, j / n))
                where.append(_where_square(i, j, n))
        tris = []
        for j in range(n):
            for i in range(n):
                a, b, c, d = index[(i, j)], index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]
                tris += [(a, b, c), (a, c, d)]
    return np.array(pts, float), np.array(tris, np.int64), tuple(where)


def _where_triangle(i: int, j: int, n: int):
    corners = {(0, 0): 0, (n, 0): 1, (0, n): 2}
    if (i, j) in corners:
        return (0, corners[(i, j)], -1, 0)
    if j == 0:
        return (1, 0, 1, i)             # edge 0 -> 1
    if i + j == n:
        return (1, 1, 2, j)             # edge 1 -> 2
    if i == 0:
        return (1, 2, 0, n - j)         # edge 2 -> 0
    return (2, -1, -1, 0)


def _where_square(i: int, j: int, n: int):
    corners = {(0, 0): 0, (n, 0): 1, (n, n): 2, (0, n): 3}
    if (i, j) in corners:
        return (0, corners[(i, j)], -1, 0)
    if j == 0:
        return (1, 0, 1, i)
    if i == n:
        return (1, 1, 2, j)
    if j == n:
        return (1, 2, 3, n - i)
    if i == 0:
        return (1, 3, 0, n - j)
    return (2, -1, -1, 0)
