"""Any specimen from a mesh: its states, the surfaces a renderer draws, and the exact truth of every pixel.

A :class:`MeshSpecimen` is a curved FE surface (:class:`scenes.specimens.surface_mesh.SurfaceMesh`), nodal displacements
per state, and paint (:mod:`scenes.surfaces.paint`). State ``k`` places the material point ``X`` at
``R_k (X + u_k(X)) + t_k`` in the world: a deformation from the FE result and/or a rigid motion of the whole
specimen (a stage), so the same object serves a loaded coupon and a cylinder moved as a rigid body.

Rendering gets the surface cut into flat pieces within a stated distance of the curved faces
(:meth:`MeshSpecimen.surfaces`: the painted part with its texture, the rest plain); the truth never looks at the
images (:meth:`MeshSpecimen.pixel_truth`): every pixel's chief ray is cast against the surface of the reference
state (:mod:`scenes.specimens.ray_surface`), refined onto the curved face, and the material point it sees is followed
through every state in both cameras, with the reasons a point cannot be measured:

=====================  =============================================================================================
``NO_SURFACE``         the ray misses the specimen (background, a hole)
``BACK_SIDE``          it meets an open surface from behind
``GRAZING``            the surface is seen more obliquely than ``grazing_limit_deg`` from its normal
``UNPAINTED``          the face carries no paint (no speckle to correlate)
``HIDDEN``             in some state or in the other camera the point is hidden (self-occlusion) or out of view
=====================  =============================================================================================
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from scenes.optics.camera import SensorSpec
from scenes.surfaces.paint import Paint, PaintLayout, layout, texture
from scenes.specimens.ray_surface import cast_rays, pixel_centre_rays, refine_on_surface, visible_from
from scenes.specimens.surface_mesh import SurfaceMesh, Tessellation
from scenes.surfaces.textured_surface import TexturedSurface

NO_SURFACE, BACK_SIDE, GRAZING, UNPAINTED, HIDDEN = 1, 2, 4, 8, 16
MASK_BITS = {"no_surface": NO_SURFACE, "back_side": BACK_SIDE, "grazing": GRAZING, "unpainted": UNPAINTED,
             "hidden": HIDDEN}
#: Default grazing limit: beyond ~70 deg a subset is foreshortened 3x and speckles smear (DIC good practice).
GRAZING_LIMIT_DEG = 70.0
#: Default distance allowed between the flat pieces drawn and the curved faces, as a fraction of a pixel footprint.
SAGITTA_PX = 0.005


@dataclass
class PixelTruth:
    """The truth of the pixels of one camera's reference image (state 0), arrays (H, W).

    Attributes
    ----------
    face : int, the surface face seen (-1: none)
    st : (H, W, 2) float, the material point's reference coordinates on that face (NaN: none)
    mask : uint8, :data:`MASK_BITS` (0: measurable)
    X_world_mm : (K, H, W, 3) float32, the material point in every state, world frame (NaN: none)
    xy_px : {"left"|"right": (K, H, W, 2) float32}, where it is imaged in each camera and state (NaN: hidden)
    """

    face: np.ndarray
    st: np.ndarray
    mask: np.ndarray
    X_world_mm: np.ndarray | None = None
    xy_px: dict = field(default_factory=dict)


class MeshSpecimen:
    """A painted FE surface with states (module docstring).

    Parameters
    ----------
    mesh : SurfaceMesh, specimen frame, mm
    displacements_mm : (K, P, 3) nodal displacements of the states (K >= 1; state 0 is the reference)
    paint : Paint
    pieces : flat pieces per face edge (None: the fewest keeping the faces within ``sagitta_mm`` in every state)
    sagitta_mm : the distance allowed between the flat pieces and the curved faces (None: 1e-3 mm)
    rigid_poses : K (R (3, 3), t (3,)) rigid motions of the specimen per state, applied in the specimen frame
        after the deformation: ``X -> R (X + u) + t`` (None: no motion)
    texture, texture_origin_mm, texture_size_mm : a texture of one's own (rows, cols) in [0, 1] covering
        ``origin + [0, size]`` of the paint's (u, v) plane (a photographed pattern; the built-in beam's), instead
        of the paint's generated one
    """

    def __init__(self, mesh: SurfaceMesh, displacements_mm, paint: Paint | None = None, *, pieces: int | None = None,
                 sagitta_mm: float | None = None, rigid_poses=None, texture=None, texture_origin_mm=None,
                 texture_size_mm=None):
        self.mesh = mesh
        U = np.asarray(displacements_mm, float)
        if U.ndim == 2:
            U = U[None]
        P = len(mesh.points_mm)
        if U.ndim != 3 or U.shape[1:] != (P, 3) or len(U) < 1:
            raise ValueError(f"{mesh.source}: displacements must be (K, {P}, 3) with K >= 1 states, got {U.shape}")
        if not np.all(np.isfinite(U)):
            k = int(np.flatnonzero(~np.all(np.isfinite(U), axis=(1, 2)))[0])
            raise ValueError(f"{mesh.source}: the displacement of state {k} is not finite")
        self.displacements_mm = U
        self.paint = Paint() if paint is None else paint
        if rigid_poses is None:
            rigid_poses = [(np.eye(3), np.zeros(3))] * len(U)
        if len(rigid_poses) != len(U):
            raise ValueError(f"{len(rigid_poses)} rigid poses for {len(U)} states")
        self.rigid_poses = [(np.asarray(R, float), np.asarray(t, float).reshape(3)) for R, t in rigid_poses]
        self.sagitta_mm = 1e-3 if sagitta_mm is None else float(sagitta_mm)
        if pieces is None:
            pieces = max(mesh.pieces_for_sagitta(self.sagitta_mm, u) for u in self._sagitta_states())
        self.tessellation: Tessellation = mesh.tessellate(int(pieces))
        V0 = mesh.tessellation_positions(self.tessellation)
        self.layout: PaintLayout = layout(self.paint, V0, self.tessellation.triangles, mesh.source)
        self._texture = None
        if texture is not None:
            tex = np.asarray(texture, np.float32)
            if tex.ndim != 2 or texture_origin_mm is None or texture_size_mm is None:
                raise ValueError("a texture of one's own needs a 2-D array, texture_origin_mm and texture_size_mm")
            self.layout = self.layout.with_texture_frame(tex.shape, texture_origin_mm, texture_size_mm)
            self._texture = tex

    def _sagitta_states(self):
        """The states whose curvature decides the pieces: the undeformed mesh and the largest displacement."""
        k = int(np.argmax(np.abs(self.displacements_mm).max(axis=(1, 2))))
        return [None, self.displacements_mm[k]]

    @property
    def n_states(self) -> int:
        return len(self.displacements_mm)

    def texture(self) -> np.ndarray:
        if self._texture is None:
            self._texture = texture(self.paint, self.layout.shape, self.layout.origin_mm)
        return self._texture

    # ---- geometry of a state
    def state_pose(self, k: int, R_world_from_specimen, t_world_from_specimen_mm) -> tuple[np.ndarray, np.ndarray]:
        """World pose of the specimen frame in state k (the placement composed with the state's rigid motion)."""
        R0 = np.asarray(R_world_from_specimen, float)
        t0 = np.asarray(t_world_from_specimen_mm, float).reshape(3)
        Rk, tk = self.rigid_poses[k]
        return R0 @ Rk, R0 @ tk + t0

    def vertices_world(self, k: int, R_world_from_specimen, t_world_from_specimen_mm) -> np.ndarray:
        """(V, 3) tessellation vertices in state k, world frame."""
        R, t = self.state_pose(k, R_world_from_specimen, t_world_from_specimen_mm)
        return self.mesh.tessellation_positions(self.tessellation, self.displacements_mm[k]) @ R.T + t

    def surfaces(self, k: int, R_world_from_specimen, t_world_from_specimen_mm) -> list[TexturedSurface]:
        """The surfaces of state k for a renderer: ``[painted (bilinear speckle or nearest checker), plain]``."""
        V = self.vertices_world(k, R_world_from_specimen, t_world_from_specimen_mm)
        T = self.tessellation.triangles
        painted = self.layout.painted
        out = [TexturedSurface(vertices_mm=V, faces=T[painted], uv=np.clip(self.layout.uv(), 0, 1),
                               texture=self.texture(),
                               filter="nearest" if self.paint.kind == "checker" else "bilinear")]
        if (~painted).any():
            out.append(TexturedSurface(vertices_mm=V, faces=T[~painted], uv=np.zeros((len(V), 2)),
                                       texture=np.full((1, 1), self.paint.base_grey, np.float32), filter="nearest"))
        return out

    # ---- truth
    def material_points(self, spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, R_world_from_specimen,
                        t_world_from_specimen_mm, k: int = 0, grazing_limit_deg: float = GRAZING_LIMIT_DEG
                        ) -> PixelTruth:
        """Per pixel of one camera's image of state k: the material point seen and why it cannot be measured
        (``NO_SURFACE``, ``BACK_SIDE``, ``GRAZING``, ``UNPAINTED``; visibility in other views is added by
        :meth:`pixel_truth`)."""
        V = self.vertices_world(k, R_world_from_specimen, t_world_from_specimen_mm)
        hits = cast_rays(spec, R_cam_from_world, t_cam_from_world_mm, V, self.tessellation.triangles)
        H, W = hits.triangle.shape
        face = np.full((H, W), -1, np.int64)
        st = np.full((H, W, 2), np.nan)
        mask = np.zeros((H, W), np.uint8)
        hit = hits.triangle >= 0
        mask[~hit] |= NO_SURFACE
        mask[hit & ~hits.front] |= BACK_SIDE
        rows, cols = np.nonzero(hit)
        tri = hits.triangle[rows, cols]
        b = hits.bary[rows, cols]
        corners = self.tessellation.triangle_st[tri]                      # (M, 3, 2)
        st0 = corners[:, 0] + b[:, :1] * (corners[:, 1] - corners[:, 0]) + b[:, 1:] * (corners[:, 2] - corners[:, 0])
        f = self.tessellation.triangle_face[tri]
        Rc = np.asarray(R_cam_from_world, float)
        tc = np.asarray(t_cam_from_world_mm, float).reshape(3)
        xy = pixel_centre_rays(spec)[rows, cols]                     # cached undistorted pixel-centre rays
        d = np.column_stack([xy, np.ones(len(xy))]) @ Rc               # world directions (rows: R^T d_cam)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        o = np.repeat((-Rc.T @ tc)[None], len(d), axis=0)
        R, t = self.state_pose(k, R_world_from_specimen, t_world_from_specimen_mm)
        st1, X, n = refine_on_surface(self.mesh, f, st0, self.displacements_mm[k], o, d, R, t, with_normals=True)
        good = np.all(np.isfinite(st1), axis=1)
        face[rows[good], cols[good]] = f[good]
        st[rows[good], cols[good]] = st1[good]
        mask[rows[~good], cols[~good]] |= NO_SURFACE
        cos_view = -np.einsum("ij,ij->i", n[good], d[good])
        graze = cos_view < np.cos(np.radians(grazing_limit_deg))
        mask[rows[good][graze], cols[good][graze]] |= GRAZING
        unpainted = ~self.layout.painted[tri[good]]
        mask[rows[good][unpainted], cols[good][unpainted]] |= UNPAINTED
        return PixelTruth(face, st, mask)

    def material_points_at(self, spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, R_world_from_specimen,
                           t_world_from_specimen_mm, pixels_xy, k: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """The material points ``(face (M,), st (M, 2))`` one camera sees at pixel positions ``pixels_xy`` (M, 2)
        (sub-pixel allowed) in state k: the chief ray of each position, started on the flat piece its nearest pixel
        centre sees and refined onto the curved deformed face
        (:func:`~scenes.specimens.ray_surface.refine_on_surface`). -1 / NaN where the ray misses the surface or
        leaves the image."""
        from scenes.optics.projection import pixel_rays

        p = np.asarray(pixels_xy, float).reshape(-1, 2)
        face = np.full(len(p), -1, np.int64)
        st = np.full((len(p), 2), np.nan)
        hits = cast_rays(spec, R_cam_from_world, t_cam_from_world_mm,
                         self.vertices_world(k, R_world_from_specimen, t_world_from_specimen_mm),
                         self.tessellation.triangles)
        H, W = hits.triangle.shape
        o_all, d_all = pixel_rays(spec, R_cam_from_world, t_cam_from_world_mm,
                                  np.where(np.isfinite(p), p, 0.0))
        R, t = self.state_pose(k, R_world_from_specimen, t_world_from_specimen_mm)
        # Seeds: the flat pieces seen at the nearest pixel centre, then at the other three around the position. A
        # position between centres whose ray crosses into the next curved face is refined on the face that holds
        # it (its (s, t) inside the face's domain), not on its neighbour's polynomial continued past the edge.
        seeds = [(np.rint(p[:, 0]), np.rint(p[:, 1]))] + [(fx(p[:, 0]), fy(p[:, 1])) for fx in (np.floor, np.ceil)
                                                          for fy in (np.floor, np.ceil)]
        settled = np.zeros(len(p), bool)
        for col, row in seeds:
            todo = (~settled & np.all(np.isfinite(p), axis=1) & (col >= 0) & (col < W) & (row >= 0) & (row < H))
            idx = np.flatnonzero(todo)
            if not len(idx):
                continue
            r, c = row[idx].astype(np.int64), col[idx].astype(np.int64)
            tri = hits.triangle[r, c]
            seen = tri >= 0
            idx, r, c, tri = idx[seen], r[seen], c[seen], tri[seen]
            if not len(idx):
                continue
            b = hits.bary[r, c]
            corners = self.tessellation.triangle_st[tri]
            st0 = corners[:, 0] + b[:, :1] * (corners[:, 1] - corners[:, 0]) + b[:, 1:] * (corners[:, 2] - corners[:, 0])
            f = self.tessellation.triangle_face[tri]
            st1, _ = refine_on_surface(self.mesh, f, st0, self.displacements_mm[k], o_all[idx], d_all[idx], R, t)
            good = np.all(np.isfinite(st1), axis=1)
            inside = good & self.mesh.inside_face(f, st1)
            first = face[idx] < 0                      # the nearest centre's answer stands unless a later one is inside
            take = inside | (good & first)
            face[idx[take]], st[idx[take]] = f[take], st1[take]
            settled[idx[inside]] = True
        return face, st

    def follow(self, face, st, cameras: dict, R_world_from_specimen, t_world_from_specimen_mm, hits_of=None
               ) -> tuple[np.ndarray, dict, np.ndarray]:
        """Material points ``(face (M,), st (M, 2))`` through every state and camera.

        Parameters
        ----------
        cameras : {"left"|"right": (SensorSpec, R_cam_from_world, t_cam_from_world_mm)}
        hits_of : callable (k, side) -> RayHits of state k in that camera (cached by the caller), or None

        Returns
        -------
        X_world_mm : (K, M, 3) positions
        xy_px : {side: (K, M, 2)} images of the points (NaN where hidden or out of view)
        visible : (K, M) bool, seen by every camera in state k
        """
        K, M = self.n_states, len(face)
        X = np.empty((K, M, 3))
        xy = {side: np.full((K, M, 2), np.nan) for side in cameras}
        visible = np.ones((K, M), bool)
        for k in range(K):
            R, t = self.state_pose(k, R_world_from_specimen, t_world_from_specimen_mm)
            X[k] = self.mesh.positions(face, st, self.displacements_mm[k]) @ R.T + t
            n = self.mesh.normals(face, st, self.displacements_mm[k]) @ R.T
            for side, (spec, Rc, tc) in cameras.items():
                hits = hits_of(k, side) if hits_of is not None else cast_rays(
                    spec, Rc, tc, self.vertices_world(k, R_world_from_specimen, t_world_from_specimen_mm),
                    self.tessellation.triangles)
                seen, p = visible_from(spec, Rc, tc, hits, X[k], n)
                xy[side][k, seen] = p[seen]
                visible[k] &= seen
        return X, xy, visible

    def paint_points(self, uv_mm, k: int = 0, tol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
        """Material points ``(face (M,), st (M, 2))`` of the curved surface where the paint's plane coordinates are
        ``uv_mm`` (M, 2) (a checker's corners): located on the painted flat pieces, then Newton on the curved face
        of the reference geometry (the paint is laid on it). -1 / NaN where no painted piece holds the point."""
        from scenes.surfaces.paint import paint_coordinates_mm

        target = np.asarray(uv_mm, float).reshape(-1, 2)
        tess, lay = self.tessellation, self.layout
        tris = np.flatnonzero(lay.painted)
        UV = lay.uv_mm[tess.triangles[tris]]                                    # (T, 3, 2)
        face = np.full(len(target), -1, np.int64)
        st = np.full((len(target), 2), np.nan)
        from scipy.spatial import cKDTree
        tree = cKDTree(UV.mean(axis=1))
        reach = float(np.max(np.linalg.norm(UV - UV.mean(axis=1, keepdims=True), axis=2)))
        for i, p in enumerate(target):
            for j in tree.query_ball_point(p, reach * 1.01):
                A, B, C = UV[j]
                M = np.column_stack([B - A, C - A])
                if abs(np.linalg.det(M)) < 1e-300:
                    continue
                b = np.linalg.solve(M, p - A)
                if b.min() >= -1e-9 and b.sum() <= 1 + 1e-9:
                    t = tris[j]
                    c = tess.triangle_st[t]
                    face[i] = tess.triangle_face[t]
                    st[i] = c[0] + b[0] * (c[1] - c[0]) + b[1] * (c[2] - c[0])
                    break
        ok = np.flatnonzero(face >= 0)
        V = self.mesh.points_mm
        r = lay.radius_mm
        h = 1e-7
        for _ in range(20):                       # Newton on uv(X(s, t)) = target, numerical Jacobian (smooth map)
            if not len(ok):
                break
            f0 = paint_coordinates_mm(self.paint, self.mesh.evaluate(face[ok], st[ok], V), r)
            J = np.empty((len(ok), 2, 2))
            for a in range(2):
                e = np.zeros(2)
                e[a] = h
                fp = paint_coordinates_mm(self.paint, self.mesh.evaluate(face[ok], st[ok] + e, V), r)
                fm = paint_coordinates_mm(self.paint, self.mesh.evaluate(face[ok], st[ok] - e, V), r)
                J[:, :, a] = (fp - fm) / (2 * h)
            step = np.linalg.solve(J, (target[ok] - f0)[:, :, None])[:, :, 0]
            st[ok] += step
            if np.abs(step).max() < tol:
                break
        return face, st

    def surface_strain(self, face, st, k: int, reference: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Exact surface Green-Lagrange strain of state k relative to state ``reference`` at material points, in the
        tangent basis Q of the reference state (:meth:`scenes.specimens.surface_mesh.SurfaceMesh.surface_strain`); a rigid
        motion of the states does not strain. Returns E (M, 2, 2) and Q (M, 3, 2) in the specimen frame."""
        return self.mesh.surface_strain(face, st, self.displacements_mm[k], self.displacements_mm[reference])

    def pixel_truth(self, cameras: dict, R_world_from_specimen, t_world_from_specimen_mm, reference_side: str = "left",
                    grazing_limit_deg: float = GRAZING_LIMIT_DEG) -> PixelTruth:
        """The full truth of ``reference_side``'s reference image: material points, masks (``HIDDEN`` where a point
        is hidden or out of view in any state or camera), positions and image points in every state."""
        cache: dict = {}

        def hits_of(k, side):
            if (k, side) not in cache:
                spec, Rc, tc = cameras[side]
                cache[(k, side)] = cast_rays(spec, Rc, tc, self.vertices_world(k, R_world_from_specimen,
                                                                                t_world_from_specimen_mm),
                                             self.tessellation.triangles)
            return cache[(k, side)]

        spec, Rc, tc = cameras[reference_side]
        pt = self.material_points(spec, Rc, tc, R_world_from_specimen, t_world_from_specimen_mm, 0, grazing_limit_deg)
        rows, cols = np.nonzero(pt.face >= 0)
        X, xy, visible = self.follow(pt.face[rows, cols], pt.st[rows, cols], cameras, R_world_from_specimen,
                                     t_world_from_specimen_mm, hits_of)
        pt.mask[rows[~visible.all(axis=0)], cols[~visible.all(axis=0)]] |= HIDDEN
        H, W = pt.face.shape
        pt.X_world_mm = np.full((self.n_states, H, W, 3), np.nan, np.float32)
        pt.X_world_mm[:, rows, cols] = X
        for side in cameras:
            pt.xy_px[side] = np.full((self.n_states, H, W, 2), np.nan, np.float32)
            pt.xy_px[side][:, rows, cols] = xy[side]
        return pt


def speckle_size_px(paint: Paint, spec: SensorSpec, distance_mm: float) -> float:
    """The paint's speckle diameter on the sensor at ``distance_mm`` from the camera, px."""
    return float(paint.speckle_mm * min(spec.fx, spec.fy) / distance_mm)


def warn_if_aliased(paint: Paint, spec: SensorSpec, distance_mm: float, what: str) -> float:
    """Warn when speckles image smaller than 2 px (aliasing: DIC bias grows; good practice is 3-5 px)."""
    size = speckle_size_px(paint, spec, distance_mm)
    if paint.kind == "speckle" and size < 2.0:
        warnings.warn(f"{what}: speckles of {paint.speckle_mm:g} mm image at {size:.2f} px (< 2 px: aliased; "
                      f"3-5 px is good practice)", stacklevel=2)
    return size
