"""The specimen's face as the designer samples it: points, normals and the ROI, in the specimen frame.

The face the cameras see is at ``z ~ 0`` facing ``-z`` (every catalog specimen, the beam, a user's mesh as the
specimen path places it). A plane is sampled on a grid over its ROI; a mesh (a catalog FE result or a user's file,
read by :func:`scenes.specimens.fe_files.read_specimen_file`) where a ray along ``+z`` through each node of the same grid first
meets it (what a camera looking along ``+z`` sees there: the near wall of a hollow specimen, never its far one), kept
where that face is a front face (outer normal within 60 deg of ``-z``). A curved face (the pressurised cylinder) keeps its depth: the
points' best-fit plane is what a tilted sensor is focused on, the rest is defocus the prediction counts.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: A face counts as front where its outer normal is within this angle of -z.
FRONT_ANGLE_DEG = 60.0


@dataclass(frozen=True)
class Surface:
    """Samples of the face.

    Attributes
    ----------
    points_mm : ndarray (N, 3)
        Specimen frame.
    normals : ndarray (N, 3)
        Unit outer normals (towards the cameras, ~ -z).
    grid_index : ndarray (N, 2) of int
        (column, row) of each sample on the ROI grid (for maps).
    grid_shape : (rows, cols)
    roi_mm : (x0, y0, x1, y1)
    label : str
    outline_mm : ndarray (K, 2)
        x, y of the face's outline (plane: its rectangle; mesh: the front faces' x-y bounding box), for drawings.
    """

    points_mm: np.ndarray
    normals: np.ndarray
    grid_index: np.ndarray
    grid_shape: tuple
    roi_mm: tuple
    label: str
    outline_mm: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 2)))

    def best_plane(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre, unit normal towards the cameras) of the least-squares plane through the samples."""
        c = self.points_mm.mean(axis=0)
        _, _, vt = np.linalg.svd(self.points_mm - c)
        n = vt[2]
        if n @ self.normals.mean(axis=0) < 0:
            n = -n
        return c, n

    def tangents(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit tangents along the specimen's x and y projected on each sample's tangent plane, (N, 3) each."""
        n = self.normals
        ex = np.array([1.0, 0.0, 0.0])
        tx = ex - (n @ ex)[:, None] * n
        tx /= np.linalg.norm(tx, axis=1, keepdims=True)
        ty = np.cross(n, tx)
        ty *= np.sign(ty[:, 1:2] + 1e-300)      # along +y
        return tx, ty

    def depth_samples(self, depth_range_mm: float) -> list[tuple[float, np.ndarray]]:
        """The samples at the reference and at both ends of the out-of-plane travel: ``[(offset_mm, points)]``;
        the face moves along its mean normal."""
        if depth_range_mm <= 0:
            return [(0.0, self.points_mm)]
        n = self.normals.mean(axis=0)
        n /= np.linalg.norm(n)
        h = 0.5 * depth_range_mm
        return [(0.0, self.points_mm), (-h, self.points_mm - h * n), (h, self.points_mm + h * n)]


def _grid(roi, samples) -> tuple[np.ndarray, np.ndarray]:
    x0, y0, x1, y1 = roi
    nx, ny = samples
    return np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)


def plane_surface(width_mm: float, height_mm: float, roi_mm=None, samples=(13, 9)) -> Surface:
    """A plane ``width x height`` mm centred on the origin, facing -z."""
    roi = tuple(roi_mm) if roi_mm is not None else (-width_mm / 2, -height_mm / 2, width_mm / 2, height_mm / 2)
    if roi[0] < -width_mm / 2 - 1e-9 or roi[2] > width_mm / 2 + 1e-9 or roi[1] < -height_mm / 2 - 1e-9 \
            or roi[3] > height_mm / 2 + 1e-9:
        raise ValueError(f"specimen.roi_mm {list(roi)} reaches outside the {width_mm:g} x {height_mm:g} mm plane "
                         f"(x in +/-{width_mm / 2:g}, y in +/-{height_mm / 2:g} mm)")
    xs, ys = _grid(roi, samples)
    X, Y = np.meshgrid(xs, ys)
    P = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    r, c = np.meshgrid(np.arange(len(ys)), np.arange(len(xs)), indexing="ij")
    outline = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]], float) * [width_mm / 2, height_mm / 2]
    return Surface(P, np.tile([0.0, 0.0, -1.0], (len(P), 1)), np.column_stack([c.ravel(), r.ravel()]),
                   (len(ys), len(xs)), roi, f"plane {width_mm:g} x {height_mm:g} mm", outline)


def _triangles(mesh) -> tuple[np.ndarray, np.ndarray]:
    """A surface mesh's faces as triangles of their corner nodes, (T, 3, 3) mm, and each triangle's unit outer
    normal of its face, (T, 3) (quads split along a diagonal)."""
    tris, norms = [], []
    P = mesh.points_mm
    for conn in mesh.faces.values():
        corners = 4 if conn.shape[1] in (4, 8, 9) else 3
        C = P[conn[:, :corners]]
        if corners == 4:
            n = np.cross(C[:, 2] - C[:, 0], C[:, 3] - C[:, 1])
            n = n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
            tris += [C[:, [0, 1, 2]], C[:, [0, 2, 3]]]
            norms += [n, n]
        else:
            n = np.cross(C[:, 1] - C[:, 0], C[:, 2] - C[:, 0])
            tris.append(C)
            norms.append(n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None])
    return np.concatenate(tris), np.concatenate(norms)


def first_hit_along_z(triangles: np.ndarray, x: float, y: float) -> tuple[float, int]:
    """Where the ray ``(x, y, -inf) -> +z`` first meets the triangles: (z mm, triangle index), or (nan, -1)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    # barycentric coordinates of (x, y) in each triangle's x-y projection
    d = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    ok = np.abs(d) > 1e-12                       # a triangle seen edge-on along z has no interior here
    d = np.where(ok, d, 1.0)
    l1 = ((b[:, 1] - c[:, 1]) * (x - c[:, 0]) + (c[:, 0] - b[:, 0]) * (y - c[:, 1])) / d
    l2 = ((c[:, 1] - a[:, 1]) * (x - c[:, 0]) + (a[:, 0] - c[:, 0]) * (y - c[:, 1])) / d
    l3 = 1.0 - l1 - l2
    eps = 1e-9
    hit = ok & (l1 >= -eps) & (l2 >= -eps) & (l3 >= -eps)
    if not hit.any():
        return float("nan"), -1
    z = l1 * a[:, 2] + l2 * b[:, 2] + l3 * c[:, 2]
    k = int(np.flatnonzero(hit)[np.argmin(z[hit])])
    return float(z[k]), k


def mesh_surface(path, unit: str = "mm", roi_mm=None, samples=(13, 9), label: str = "") -> Surface:
    """The front face of a mesh or FE file (module notes)."""
    from scenes.specimens.fe_files import read_specimen_file

    sf = read_specimen_file(path, unit=unit, steps=[0]) if _has_fields(path) else read_specimen_file(path, unit=unit)
    tris, norms = _triangles(sf.mesh)
    front = norms[:, 2] < -np.cos(np.radians(FRONT_ANGLE_DEG))
    if not front.any():
        raise ValueError(f"{path}: no face of the mesh faces the cameras (-z within {FRONT_ANGLE_DEG:g} deg)")
    cents = tris[front].mean(axis=1)
    lo, hi = cents[:, :2].min(axis=0), cents[:, :2].max(axis=0)
    roi = tuple(roi_mm) if roi_mm is not None else (lo[0], lo[1], hi[0], hi[1])
    xs, ys = _grid(roi, samples)
    pts, nrm, idx = [], [], []
    for r, y in enumerate(ys):
        for c, x in enumerate(xs):
            z, k = first_hit_along_z(tris, x, y)
            if k < 0 or not front[k]:           # a hole, beyond the edge, or a face seen edge-on: no sample
                continue
            pts.append([x, y, z])
            nrm.append(norms[k])
            idx.append([c, r])
    if len(pts) < 4:
        raise ValueError(f"{path}: fewer than 4 samples of the front face inside specimen.roi_mm {list(roi)}")
    outline = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]], [lo[0], lo[1]]])
    return Surface(np.asarray(pts), np.asarray(nrm), np.asarray(idx, int), (len(ys), len(xs)), roi,
                   label or Path(path).name, outline)


def _has_fields(path) -> bool:
    return Path(path).suffix.lower() in (".vtu", ".vtk", ".pvd", ".msh", ".inp", ".e", ".exo")


def catalog_file(name: str, folder) -> Path:
    """Write catalog specimen ``name``'s FE result into ``folder`` (once) and return its ``.pvd``."""
    from scenes.specimens.catalog import CATALOG, write_pvd

    folder = Path(folder)
    existing = sorted(folder.glob("*.pvd")) if folder.is_dir() else []
    if existing:
        return existing[0]
    folder.mkdir(parents=True, exist_ok=True)
    return write_pvd(CATALOG[name](), folder)


def surface_of(specimen, folder) -> tuple[Surface, Path | None]:
    """The design's face (:class:`workbench.design.inputs.SpecimenInput`) and the specimen file behind it (None
    for a plane); a catalog specimen's FE result is written under ``folder``."""
    if specimen.plane_mm is not None:
        return plane_surface(*specimen.plane_mm, specimen.roi_mm, specimen.sample_points), None
    if specimen.catalog:
        path = catalog_file(specimen.catalog, Path(folder) / specimen.catalog)
        return mesh_surface(path, "mm", specimen.roi_mm, specimen.sample_points, specimen.catalog), path
    return mesh_surface(specimen.mesh, specimen.unit, specimen.roi_mm, specimen.sample_points), Path(specimen.mesh)


def resampled(specimen, specimen_path, samples) -> Surface:
    """The design's face sampled on another ``samples`` (columns, rows) grid over the same ROI, from the specimen
    file already made (None for a plane)."""
    if specimen.plane_mm is not None:
        return plane_surface(*specimen.plane_mm, specimen.roi_mm, samples)
    unit = "mm" if specimen.catalog else specimen.unit
    return mesh_surface(specimen_path, unit, specimen.roi_mm, samples, specimen.catalog or "")
