"""Emissive textured triangle meshes: the one surface type every rendered object uses.

A printed or speckle-painted surface under uniform, diffuse illumination looks like a surface that emits
its albedo: rendering it as an area emitter with the albedo as radiance texture gives the same image with
no lighting noise, so each pixel is the exact area integral of the pattern (up to pixel sampling).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.optics.backend import mi


@dataclass(frozen=True)
class TexturedSurface:
    """A triangle mesh with texture coordinates and an emitted-radiance texture.

    Parameters
    ----------
    vertices_mm : (V, 3) float, world frame, mm
    faces : (F, 3) int, counter-clockwise seen from the emitting (visible) side
    uv : (V, 2) float in [0, 1]; texture row r covers ``uv[1]`` in [r/rows, (r+1)/rows]
    texture : (rows, cols) float, emitted radiance
    filter : "nearest" (sharp-edged prints) or "bilinear" (smooth speckle textures)
    """

    vertices_mm: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    filter: str = "bilinear"

    def __post_init__(self):
        v, f, uv, tex = (np.asarray(a) for a in (self.vertices_mm, self.faces, self.uv, self.texture))
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices_mm must be (V, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"faces must be (F, 3) indices into {len(v)} vertices")
        if uv.shape != (len(v), 2):
            raise ValueError(f"uv must be ({len(v)}, 2), got {uv.shape}")
        if tex.ndim != 2 or not np.all(np.isfinite(tex)):
            raise ValueError(f"texture must be a finite 2-D array, got shape {tex.shape}")
        if self.filter not in ("nearest", "bilinear"):
            raise ValueError(f"filter must be 'nearest' or 'bilinear', got {self.filter!r}")

    def to_mitsuba(self, name: str = "surface"):
        """A ``mi.Mesh`` with an area emitter textured by ``texture`` (and a black BSDF)."""
        props = mi.Properties()
        props["emitter"] = mi.load_dict({
            "type": "area",
            "radiance": {"type": "bitmap", "data": mi.TensorXf(np.ascontiguousarray(self.texture, dtype=np.float32)[..., None]),
                         "raw": True, "filter_type": self.filter, "wrap_mode": "clamp"}})
        props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.0}})
        mesh = mi.Mesh(name, len(self.vertices_mm), len(self.faces), props=props, has_vertex_texcoords=True)
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(np.ascontiguousarray(self.vertices_mm, dtype=np.float32).ravel())
        params["faces"] = mi.UInt32(np.ascontiguousarray(self.faces, dtype=np.uint32).ravel())
        params["vertex_texcoords"] = mi.Float(np.ascontiguousarray(self.uv, dtype=np.float32).ravel())
        params.update()
        return mesh
