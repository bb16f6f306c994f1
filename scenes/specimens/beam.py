"""The three-point-bending beam as a speckled trimesh solid (truth side): the specimen of the paper's bending test.

Specimen frame (mm): origin at the centre of the painted face, x along the length, y along the height pointing
down, z into the material (the painted face looks along -z, towards the cameras). Its finite-element solution is
:mod:`scenes.deformation.beam_bending`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
import trimesh

from scenes.surfaces.speckle import speckle_pattern
from scenes.surfaces.textured_surface import TexturedSurface


@dataclass(frozen=True)
class BendingSpecimen:
    """The aluminium three-point-bending beam: a box solid with a speckle-painted front face.

    Dimensions: **120 mm long (x) x 30 mm high (y) x 10 mm thick (z)** by default, a plausible aluminium
    3-point-bending beam (100 mm span between the supports, span/height 3.3). Placed at the paper rig's
    working distance (376 mm, where the optical axes meet) the two images share a field only ~72 mm wide,
    because Table 1's principal points are far from the image centres (cx = 869 px left, 1503 px right, of
    2456): a 120 mm beam fills the full width of *both* images with its ends out of view, as in the paper's
    bending test where the cameras see the middle of the beam. Its 30 mm height is ~40 % of the 71 mm-high
    view, leaving room for the 10 mm stage travel.

    Speckle defaults are sized for the paper rig at full resolution: a pixel covers ~0.0345 mm at 376 mm
    (fx ~ 10 900 px; 2456 px across ~85 mm), so ``texel_mm = 0.01`` gives ~3.5 texels per pixel and
    ``speckle_mm = 0.17`` speckles of ~5 px. For reduced-resolution renders use :meth:`for_pixel_size`.

    Specimen frame (mm): origin at the centre of the front face, x along the length, y along the height
    (pointing down when the beam stands as in the rig, like the camera's y), z along the thickness into the
    material. The front face ``z = 0`` looks along -z, towards the cameras; the solid fills
    ``|x| <= length/2, |y| <= height/2, 0 <= z <= thickness``.

    Every face is a grid of ``grid_mm`` quads (two triangles each) sharing vertex positions along the
    edges, so a displacement field applied to the vertices (``surfaces(displacement_mm=...)``) keeps the
    solid closed; the front face's texture coordinates are its material coordinates
    ``u = (x + length/2) / length``, ``v = (y + height/2) / height`` (texture row 0 at y = -height/2) and do
    not move with the material.

    Parameters
    ----------
    length_mm, height_mm, thickness_mm : beam size (> 0)
    texel_mm : speckle texture resolution on the face (> 0)
    speckle_mm : nominal speckle diameter (> 0)
    density, contrast, mean : see :func:`scenes.surfaces.speckle.speckle_pattern`
    seed : speckle seed
    grid_mm : target edge length of the surface grid (> 0); the grid divides each edge evenly
    side_grey : emitted radiance of the unpainted faces (plain mid-grey aluminium), in [0, 1]
    """

    length_mm: float = 120.0
    height_mm: float = 30.0
    thickness_mm: float = 10.0
    texel_mm: float = 0.01
    speckle_mm: float = 0.17
    density: float = 0.5
    contrast: float = 0.8
    mean: float = 0.5
    seed: int = 0
    grid_mm: float = 1.0
    side_grey: float = 0.5

    #: Largest speckle texture (texels) accepted: ~320 MB of float32.
    MAX_TEXELS = 80_000_000

    def __post_init__(self):
        for name in ("length_mm", "height_mm", "thickness_mm", "texel_mm", "speckle_mm", "grid_mm"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")
        if not 0.0 <= self.side_grey <= 1.0:
            raise ValueError(f"side_grey must be in [0, 1], got {self.side_grey}")
        rows, cols = self.texture_shape
        if rows * cols > self.MAX_TEXELS:
            raise ValueError(f"speckle texture of {cols} x {rows} texels is too large; increase texel_mm")
        if self.speckle_mm < 2 * self.texel_mm:
            raise ValueError(f"speckle_mm={self.speckle_mm} is under 2 texels of {self.texel_mm} mm: the texture "
                             f"cannot resolve it")

    @classmethod
    def for_pixel_size(cls, pixel_mm: float, speckle_px: float = 5.0, texels_per_px: float = 3.5,
                       **kwargs) -> "BendingSpecimen":
        """A specimen whose speckle suits a camera whose pixel covers ``pixel_mm`` on the face.

        ``speckle_mm = speckle_px * pixel_mm``, ``texel_mm = pixel_mm / texels_per_px``; other fields as given.
        """
        if not (np.isfinite(pixel_mm) and pixel_mm > 0):
            raise ValueError(f"pixel_mm must be positive and finite, got {pixel_mm}")
        return cls(texel_mm=pixel_mm / texels_per_px, speckle_mm=speckle_px * pixel_mm, **kwargs)

    def to_dict(self) -> dict:
        return asdict(self)

    # --------------------------------------------------------------------------------------------------------
    @property
    def texture_shape(self) -> tuple[int, int]:
        """(rows, cols) of the speckle texture: rows along y (height), cols along x (length)."""
        return int(np.ceil(self.height_mm / self.texel_mm)), int(np.ceil(self.length_mm / self.texel_mm))

    def texture(self) -> np.ndarray:
        """Speckle radiance texture of the front face, (rows, cols) float32; row 0 at y = -height/2."""
        rows, _ = self.texture_shape
        # The texture stretches over the face, so its texels are height/rows (<= texel_mm) in size.
        return speckle_pattern(self.texture_shape, self.speckle_mm * rows / self.height_mm,
                               density=self.density, contrast=self.contrast, mean=self.mean, seed=self.seed)

    def front_face_corners_mm(self) -> np.ndarray:
        """Corners of the front face in the specimen frame, (4, 3): (-x,-y), (+x,-y), (+x,+y), (-x,+y)."""
        L, H = 0.5 * self.length_mm, 0.5 * self.height_mm
        return np.array([[-L, -H, 0.0], [L, -H, 0.0], [L, H, 0.0], [-L, H, 0.0]])

    def _faces(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The six grid faces in the specimen frame: name -> (vertices (V, 3), triangles (F, 3))."""
        L, H, T = self.length_mm, self.height_mm, self.thickness_mm
        x0, y0 = -0.5 * L, -0.5 * H
        X, Y, Z = np.array([L, 0.0, 0.0]), np.array([0.0, H, 0.0]), np.array([0.0, 0.0, T])
        # (corner, edge_a, edge_b) with edge_a x edge_b along the outward normal (the emitting side).
        layout = {
            "front": ([x0, y0, 0.0], Y, X),        # normal -z, towards the cameras
            "back": ([x0, y0, T], X, Y),           # +z
            "top": ([x0, y0, 0.0], X, Z),          # -y
            "bottom": ([x0, -y0, 0.0], Z, X),      # +y
            "end_minus_x": ([x0, y0, 0.0], Z, Y),  # -x
            "end_plus_x": ([-x0, y0, 0.0], Y, Z),  # +x
        }
        return {name: self._grid(np.array(c), a, b) for name, (c, a, b) in layout.items()}

    def _grid(self, corner: np.ndarray, edge_a: np.ndarray, edge_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n_a = max(1, int(np.ceil(np.linalg.norm(edge_a) / self.grid_mm)))
        n_b = max(1, int(np.ceil(np.linalg.norm(edge_b) / self.grid_mm)))
        # Same formula corner + (i/n) edge on every face, so vertices on shared edges coincide bit for bit.
        fa, fb = np.meshgrid(np.arange(n_a + 1) / n_a, np.arange(n_b + 1) / n_b, indexing="ij")
        verts = corner + fa.reshape(-1, 1) * edge_a + fb.reshape(-1, 1) * edge_b
        idx = np.arange((n_a + 1) * (n_b + 1)).reshape(n_a + 1, n_b + 1)
        v00, v10, v11, v01 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
        tris = np.concatenate([np.stack([v00, v10, v11], -1).reshape(-1, 3),
                               np.stack([v00, v11, v01], -1).reshape(-1, 3)])
        return verts, tris

    def solid(self) -> trimesh.Trimesh:
        """The closed beam surface in the specimen frame (watertight, outward normals, volume L*H*T)."""
        verts, tris = _merge_meshes(list(self._faces().values()))
        return trimesh.Trimesh(vertices=verts, faces=tris, process=True)   # process: merge shared edges

    def surfaces(self, R_world_from_specimen: np.ndarray, t_world_from_specimen_mm: np.ndarray,
                 texture: np.ndarray | None = None,
                 displacement_mm: Callable[[np.ndarray], np.ndarray] | None = None) -> list[TexturedSurface]:
        """The beam placed at ``X_world = R (X + u(X)) + t``, as two emissive meshes.

        Parameters
        ----------
        R_world_from_specimen : (3, 3) rotation
        t_world_from_specimen_mm : (3,) mm
        texture : (rows, cols) float, optional
            A texture from :meth:`texture`, to avoid regenerating it for every state.
        displacement_mm : callable, optional
            ``u(X_specimen (N, 3) mm) -> (N, 3) mm``, in the specimen frame, applied to every surface vertex
            (the front face moves with its grid; texture coordinates stay on the material). Faces are flat
            between grid vertices. None (or u = 0) gives the rigid beam.

        Returns
        -------
        list of TexturedSurface
            ``[front face (speckle, bilinear), the other five faces (plain side_grey)]``, world frame.
        """
        R = np.asarray(R_world_from_specimen, dtype=float)
        t = np.asarray(t_world_from_specimen_mm, dtype=float).reshape(-1)
        if R.shape != (3, 3) or t.shape != (3,) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) \
                or np.linalg.det(R) < 0:
            raise ValueError("pose must be a (3, 3) proper rotation and a (3,) translation in mm")
        tex = self.texture() if texture is None else np.asarray(texture)
        if tex.shape != self.texture_shape:
            raise ValueError(f"texture must have shape {self.texture_shape}, got {tex.shape}")
        faces = self._faces()

        def place(X: np.ndarray) -> np.ndarray:
            if displacement_mm is not None:
                U = np.asarray(displacement_mm(X.copy()), dtype=float)
                if U.shape != X.shape or not np.all(np.isfinite(U)):
                    raise ValueError(f"displacement_mm must return finite values of shape {X.shape}, got {U.shape}")
                X = X + U
            return X @ R.T + t

        front_v, front_f = faces.pop("front")
        uv = np.stack([(front_v[:, 0] + 0.5 * self.length_mm) / self.length_mm,
                       (front_v[:, 1] + 0.5 * self.height_mm) / self.height_mm], axis=1)
        front = TexturedSurface(vertices_mm=place(front_v), faces=front_f, uv=np.clip(uv, 0.0, 1.0),
                                texture=tex, filter="bilinear")
        side_v, side_f = _merge_meshes(list(faces.values()))
        sides = TexturedSurface(vertices_mm=place(side_v), faces=side_f, uv=np.zeros((len(side_v), 2)),
                                texture=np.full((1, 1), self.side_grey, dtype=np.float32), filter="nearest")
        return [front, sides]


def _merge_meshes(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (vertices (V_i, 3), triangles (F_i, 3)) meshes into one, re-indexing the triangles."""
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    return (np.concatenate([v for v, _ in parts]),
            np.concatenate([f + o for (_, f), o in zip(parts, offsets, strict=True)]))
