"""An independent interpolation of a volume FE result, for tests only: nodal displacements on tetra, hexahedron
and wedge cells, evaluated with each element's own shape functions (point location by Newton per element).

The product reads a user's FE result one way, as the surface the cameras see (:mod:`scenes.specimens.fe_files`,
:mod:`scenes.specimens.surface_mesh`); this *volume* interpolation, the project's earlier reader of FE results
(``fe_reference.FEMeshField`` until issue 41), stays here as a second implementation to check the catalog's
solutions (stresses inside the body) and the surface path against.
"""
from __future__ import annotations

import os

import numpy as np

from scenes.deformation.displacement_field import (DisplacementField, SupportsDisplacementField, as_points,
                                                   field_contains, raise_outside)
from scenes.deformation.fe_elements import ELEMENT_ALIASES, EXODUS_REORDERED, REFERENCE_ELEMENTS, ReferenceElement
from scenes.specimens.fe_files import displacement_array


class FEMeshField(DisplacementField):
    """Nodal displacements on a volume mesh, interpolated with each element's own shape functions.

    Supported cells (VTK node order, as meshio uses it): ``tetra`` (4), ``tetra10``, ``hexahedron`` (8),
    ``hexahedron20`` (serendipity), ``hexahedron27``, ``wedge`` (6); isoparametric, so curved quadratic
    elements work. Other cells (surfaces, lines, unsupported volume types) are ignored; a mesh with no
    supported volume cell is refused. A point is located by a k-d tree over element centres and a Newton
    inversion of the element map; points in no element raise ValueError (see :meth:`contains`).

    Parameters
    ----------
    points_mm : (P, 3) node coordinates in the specimen frame, mm
    cells : dict cell type -> (E, nn) int node indices
    displacement_mm : (P, 3) nodal displacements, mm
    source : a name for messages (the file)
    """

    #: Tolerance on the reference coordinates for "inside an element" (relative to the element size).
    INSIDE_TOL = 1e-8

    def __init__(self, points_mm, cells: dict, displacement_mm, source: str = "<mesh>"):
        from scipy.spatial import cKDTree

        self.source = str(source)
        P = np.asarray(points_mm, dtype=float)
        U = np.asarray(displacement_mm, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or U.shape != P.shape:
            raise ValueError(f"{self.source}: points (P, 3) and displacement (P, 3) needed, got {P.shape} and "
                             f"{U.shape}")
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(U))):
            raise ValueError(f"{self.source}: node coordinates and displacements must be finite")
        self.points_mm, self.nodal_displacement_mm = P, U
        self.cells: dict[str, np.ndarray] = {}
        for name, conn in cells.items():
            conn = np.asarray(conn, dtype=np.int64)
            ref = REFERENCE_ELEMENTS[name]
            if conn.ndim != 2 or conn.shape[1] != len(ref.nodes) or conn.min() < 0 or conn.max() >= len(P):
                raise ValueError(f"{self.source}: bad {name} connectivity of shape {conn.shape}")
            if len(conn):
                self.cells[name] = conn
        if not self.cells:
            raise ValueError(f"{self.source}: no volume cells")
        # A flat list of all elements (type, row) for the k-d tree over element centres.
        self._types = list(self.cells)
        self._elem_type = np.concatenate([np.full(len(c), k) for k, c in enumerate(self.cells.values())])
        self._elem_row = np.concatenate([np.arange(len(c)) for c in self.cells.values()])
        centres, radii, lo, hi = [], [], [], []
        for name, conn in self.cells.items():
            Xe = P[conn]
            c = Xe[:, : REFERENCE_ELEMENTS[name].n_corners].mean(axis=1)
            centres.append(c)
            radii.append(np.linalg.norm(Xe - c[:, None], axis=2).max(axis=1))
            # Node bounding box, enlarged: curved quadratic elements bulge a little past their nodes.
            a, b = Xe.min(axis=1), Xe.max(axis=1)
            pad = 0.1 * (b - a).max(axis=1, keepdims=True) + 1e-9 * (1 + np.abs(Xe).max(axis=(1, 2)))[:, None]
            lo.append(a - pad)
            hi.append(b + pad)
        self._centres = np.concatenate(centres)
        self._lo, self._hi = np.concatenate(lo), np.concatenate(hi)
        self._radius = 1.25 * float(np.concatenate(radii).max())   # margin: curved elements bulge past nodes
        self._tree = cKDTree(self._centres)
        for a in (self.points_mm, self.nodal_displacement_mm):
            a.setflags(write=False)

    def __repr__(self):
        counts = ", ".join(f"{len(c)} {n}" for n, c in self.cells.items())
        return f"FEMeshField({self.source!r}: {len(self.points_mm)} nodes, {counts})"

    # ---- reading
    @classmethod
    def from_meshio(cls, mesh, displacement_name: str | tuple[str, str, str] | None = None, *,
                    source: str = "<meshio.Mesh>", scale_to_mm: float = 1.0,
                    R_specimen_from_mesh=None, t_specimen_from_mesh_mm=None,
                    exodus: bool = False) -> "FEMeshField":
        """A field from a ``meshio.Mesh``; see :meth:`from_file` for the parameters."""
        cells: dict[str, list] = {}
        found = []
        for block in mesh.cells:
            name = ELEMENT_ALIASES.get(block.type, block.type)
            found.append(block.type)
            if name in REFERENCE_ELEMENTS:
                if exodus and name in EXODUS_REORDERED:
                    raise ValueError(f"{source}: {name} cells from Exodus are not supported (Exodus orders their "
                                     f"mid-edge/face nodes differently from VTK and meshio does not reorder them); "
                                     f"export VTU instead")
                cells.setdefault(name, []).append(np.asarray(block.data))
        if not cells:
            raise ValueError(f"{source}: no volume cells of a supported type ({', '.join(sorted(REFERENCE_ELEMENTS))}); "
                             f"the file has: {', '.join(sorted(set(found))) or 'no cells'}")
        U = displacement_array(mesh.point_data, len(mesh.points), displacement_name, source)
        s = float(scale_to_mm)
        if not (np.isfinite(s) and s > 0):
            raise ValueError(f"scale_to_mm must be positive, got {scale_to_mm}")
        R = np.eye(3) if R_specimen_from_mesh is None else np.asarray(R_specimen_from_mesh, dtype=float)
        t = np.zeros(3) if t_specimen_from_mesh_mm is None else np.asarray(t_specimen_from_mesh_mm, float).reshape(3)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("R_specimen_from_mesh must be a (3, 3) proper rotation")
        P = np.asarray(mesh.points, dtype=float)
        if P.shape[1] == 2:
            raise ValueError(f"{source}: a 2-D mesh; a volume mesh is needed")
        return cls(s * P @ R.T + t, {k: np.concatenate(v) for k, v in cells.items()}, s * U @ R.T, source=source)

    @classmethod
    def from_file(cls, path, displacement_name: str | tuple[str, str, str] | None = None, *,
                  scale_to_mm: float = 1.0, R_specimen_from_mesh=None, t_specimen_from_mesh_mm=None,
                  file_format: str | None = None) -> "FEMeshField":
        """Read nodal displacements on a volume mesh with meshio.

        Parameters
        ----------
        path : a mesh file meshio reads (tested: VTU, legacy VTK; Exodus ``.e``/``.exo`` needs netCDF4, and
            meshio reads only its first time step)
        displacement_name : point-data array (P, 3), or three scalar arrays (x, y, z); None picks the one
            vector array named like a displacement (``displacement``, ``disp``, ``u``, ...) or the only
            (P, 3) array
        scale_to_mm : file length unit in mm (1000 for metres): applied to coordinates and displacements
        R_specimen_from_mesh, t_specimen_from_mesh_mm : the file's frame in the specimen frame,
            ``X_specimen = R (s X_file) + t``, displacements rotated by R (default identity)
        file_format : meshio's format name, if the extension does not tell

        Raises
        ------
        ValueError
            The file is not a mesh meshio can read, has no supported volume cells, or the displacement array
            is missing or ambiguous (the message names the file and the available arrays).
        """
        import meshio

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{path}: no such file")
        try:
            mesh = meshio.read(path, file_format=file_format)
        except (Exception, SystemExit) as exc:   # meshio raises many types, and exits on some unreadable files
            raise ValueError(f"{path}: not a mesh file meshio can read ({type(exc).__name__}: {exc})") from exc
        exodus = (file_format or "").lower() == "exodus" or path.lower().endswith((".e", ".exo", ".ex2"))
        return cls.from_meshio(mesh, displacement_name, source=path, scale_to_mm=scale_to_mm,
                               R_specimen_from_mesh=R_specimen_from_mesh,
                               t_specimen_from_mesh_mm=t_specimen_from_mesh_mm, exodus=exodus)

    # ---- location and evaluation
    def _newton(self, ref: ReferenceElement, Xe: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference coordinates of points p (M, 3) in elements with nodes Xe (M, nn, 3), and the violation."""
        xi = np.broadcast_to(ref.centre, p.shape).copy()
        converged = np.zeros(len(p), dtype=bool)
        active = np.arange(len(p))
        for _ in range(30):
            N, dN = ref.shape(xi[active])
            Xa = Xe[active]
            r = p[active] - np.einsum("ma,mak->mk", N, Xa)
            J = np.einsum("mad,mak->mkd", dN, Xa)
            good = np.abs(np.linalg.det(J)) > 1e-300
            J[~good] = np.eye(3)
            step = np.linalg.solve(J, r[:, :, None])[:, :, 0]
            xi[active] = np.clip(xi[active] + step, -1.0, 2.0)      # keep far-off candidates from diverging
            done = np.abs(step).max(axis=1) < 1e-13
            converged[active[done & good]] = True
            # Drop converged, degenerate and clearly-outside candidates (stuck at the clip box).
            stuck = np.any((xi[active] <= -1.0) | (xi[active] >= 2.0), axis=1)
            active = active[~done & good & ~stuck]
            if not len(active):
                break
        viol = ref.violation(xi)
        return xi, np.where(converged, viol, np.inf)

    def _test(self, X: np.ndarray, elems: np.ndarray, best: dict) -> None:
        """Try global elements ``elems`` (M,) for points ``X`` (M, 3); keep the least violating per point."""
        # Cheap rejection first: the point must lie in the element's (enlarged) bounding box.
        inbox = np.all((X >= self._lo[elems]) & (X <= self._hi[elems]), axis=1)
        for k, name in enumerate(self._types):
            sel = np.flatnonzero(inbox & (self._elem_type[elems] == k))
            if not len(sel):
                continue
            ref = REFERENCE_ELEMENTS[name]
            rows = self._elem_row[elems[sel]]
            xi, viol = self._newton(ref, self.points_mm[self.cells[name][rows]], X[sel])
            better = viol < best["viol"][sel]
            s = sel[better]
            best["viol"][s], best["type"][s], best["row"][s], best["xi"][s] = viol[better], k, rows[better], xi[better]

    def _locate(self, X: np.ndarray, chunk: int = 20000) -> dict:
        n = len(X)
        best = {"viol": np.full(n, np.inf), "type": np.full(n, -1), "row": np.full(n, -1), "xi": np.zeros((n, 3))}
        k = min(8, len(self._centres))
        for s in range(0, n, chunk):
            idx = np.arange(s, min(n, s + chunk))
            _, cand = self._tree.query(X[idx], k=k)
            cand = cand.reshape(len(idx), -1)
            for j in range(cand.shape[1]):       # nearest centres first; stop trying for found points
                todo = idx[best["viol"][idx] > self.INSIDE_TOL]
                if not len(todo):
                    break
                sub = {key: v[todo] for key, v in best.items()}
                self._test(X[todo], cand[todo - s, j], sub)
                for key in best:
                    best[key][todo] = sub[key]
        # Fallback: every element whose bounding sphere can hold the point.
        todo = np.flatnonzero(best["viol"] > self.INSIDE_TOL)
        if len(todo):
            lists = self._tree.query_ball_point(X[todo], r=self._radius)
            counts = np.array([len(c) for c in lists])
            if counts.sum():
                pts = np.repeat(todo, counts)
                elems = np.concatenate([np.asarray(c, dtype=np.int64) for c in lists if len(c)])
                sub = {"viol": np.full(len(pts), np.inf), "type": np.full(len(pts), -1),
                       "row": np.full(len(pts), -1), "xi": np.zeros((len(pts), 3))}
                self._test(X[pts], elems, sub)
                order = np.lexsort((sub["viol"], pts))           # per point, least violation first
                first = order[np.r_[True, pts[order][1:] != pts[order][:-1]]]
                for key in best:
                    better = sub["viol"][first] < best["viol"][pts[first]]
                    best[key][pts[first][better]] = sub[key][first][better]
        best["inside"] = best["viol"] <= self.INSIDE_TOL
        return best

    def contains(self, X_specimen_mm):
        """(N,) bool: points inside some element (within ``INSIDE_TOL`` of its reference domain)."""
        return self._locate(as_points(X_specimen_mm))["inside"]

    def _evaluate(self, X_specimen_mm, gradient: bool) -> np.ndarray:
        X = as_points(X_specimen_mm)
        loc = self._locate(X)
        raise_outside(X, loc["inside"], f"the mesh of {self.source}")
        out = np.empty((len(X), 3, 3) if gradient else (len(X), 3))
        for k, name in enumerate(self._types):
            sel = np.flatnonzero(loc["type"] == k)
            if not len(sel):
                continue
            conn = self.cells[name][loc["row"][sel]]
            N, dN = REFERENCE_ELEMENTS[name].shape(loc["xi"][sel])
            Ue = self.nodal_displacement_mm[conn]
            if not gradient:
                out[sel] = np.einsum("ma,mai->mi", N, Ue)
                continue
            J = np.einsum("mad,mak->mkd", dN, self.points_mm[conn])          # dx_k / dxi_d
            Gref = np.einsum("mad,mai->mid", dN, Ue)                         # du_i / dxi_d
            out[sel] = np.einsum("mid,mdj->mij", Gref, np.linalg.inv(J))
        return out

    def displacement_mm(self, X_specimen_mm):
        return self._evaluate(X_specimen_mm, gradient=False)

    def gradient(self, X_specimen_mm):
        """Gradient of the interpolant, ``dN/dX = dN/dxi J^-1`` (exact for it), (N, 3, 3)."""
        return self._evaluate(X_specimen_mm, gradient=True)

    def check_covers_face(self, length_mm: float, height_mm: float, n: int = 121, z_mm: float = 0.0) -> "FEMeshField":
        """:func:`check_covers_face` on this field; returns self."""
        check_covers_face(self, length_mm, height_mm, n=n, z_mm=z_mm)
        return self





def check_covers_face(field: SupportsDisplacementField, length_mm: float, height_mm: float, n: int = 121,
                      z_mm: float = 0.0) -> None:
    """Refuse a field whose domain does not cover the specimen's front face.

    Samples the face ``|x| <= length/2, |y| <= height/2`` at ``z = z_mm`` on a grid of ``n`` points along x
    (and the same spacing along y, at least 3 points), edges included, and asks ``field.contains``.

    Raises
    ------
    ValueError
        Naming how many sample points are uncovered, their fraction and their bounding box (mm).
    """
    if not (length_mm > 0 and height_mm > 0 and n >= 2):
        raise ValueError("length_mm and height_mm must be positive and n >= 2")
    ny = max(3, int(round((n - 1) * height_mm / length_mm)) + 1)     # about the x spacing
    xs = np.linspace(-length_mm / 2, length_mm / 2, int(n))
    ys = np.linspace(-height_mm / 2, height_mm / 2, ny)
    Xg, Yg = np.meshgrid(xs, ys, indexing="ij")
    P = np.stack([Xg.ravel(), Yg.ravel(), np.full(Xg.size, float(z_mm))], axis=1)
    inside = field_contains(field, P)
    if not inside.all():
        U = P[~inside]
        lo, hi = U.min(axis=0), U.max(axis=0)
        raise ValueError(
            f"{getattr(field, 'source', type(field).__name__)} does not cover the {length_mm:g} x {height_mm:g} mm "
            f"front face at z = {z_mm:g} mm: {len(U)} of {len(P)} sample points ({100 * len(U) / len(P):.1f} %) "
            f"are uncovered, in the region x in [{lo[0]:.6g}, {hi[0]:.6g}] mm, y in [{lo[1]:.6g}, {hi[1]:.6g}] mm")
