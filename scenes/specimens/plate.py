"""A flat speckled plate (truth side): the specimen of the paper's rigid-motion test.

Specimen frame (mm): origin at the centre of the painted face, x and y in that face, z into the material
(the painted face looks along -z, towards the cameras).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.surfaces.speckle import speckle_pattern
from scenes.surfaces.textured_surface import TexturedSurface


@dataclass(frozen=True)
class SpeckledPlate:
    """A flat plate painted with a random speckle pattern.

    Parameters
    ----------
    width_mm, height_mm : plate size
    texel_mm : texture resolution on the plate; choose a few texels per image pixel (band-limited texture)
    speckle_mm : nominal speckle diameter on the plate
    density, contrast, mean : see :func:`scenes.surfaces.speckle.speckle_pattern`
    seed : speckle seed
    """

    width_mm: float
    height_mm: float
    texel_mm: float
    speckle_mm: float
    density: float = 0.5
    contrast: float = 0.8
    mean: float = 0.5
    seed: int = 0

    def __post_init__(self):
        for name in ("width_mm", "height_mm", "texel_mm", "speckle_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        cols, rows = self.texture_shape[1], self.texture_shape[0]
        if rows * cols > 80_000_000:
            raise ValueError(f"speckle texture of {cols} x {rows} texels is too large; increase texel_mm")

    @property
    def texture_shape(self) -> tuple[int, int]:
        return int(np.ceil(self.height_mm / self.texel_mm)), int(np.ceil(self.width_mm / self.texel_mm))

    def texture(self) -> np.ndarray:
        """Speckle radiance texture, row 0 at y = -height/2, shape (rows, cols)."""
        return speckle_pattern(self.texture_shape, self.speckle_mm / self.texel_mm, density=self.density,
                               contrast=self.contrast, mean=self.mean, seed=self.seed)

    def surface(self, R_world_from_plate: np.ndarray, t_world_from_plate_mm: np.ndarray,
                texture: np.ndarray | None = None) -> TexturedSurface:
        """The plate placed at ``X_world = R X_plate + t``; pass ``texture`` to reuse a generated one."""
        w, h = self.width_mm / 2, self.height_mm / 2
        corners = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]], dtype=float)
        uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
        faces = np.array([[0, 2, 1], [0, 3, 2]])  # normal -z: the painted face looks at the cameras
        verts = corners @ np.asarray(R_world_from_plate, float).T + np.asarray(t_world_from_plate_mm, float).reshape(3)
        tex = self.texture() if texture is None else texture
        return TexturedSurface(vertices_mm=verts, faces=faces, uv=uv, texture=tex, filter="bilinear")

