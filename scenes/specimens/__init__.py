"""Specimens (truth side, floor 4 of ``scenes/``): bodies with paint, their states, and the exact truth of a pixel.

* the paper's own: :mod:`~scenes.specimens.plate` (the rigid-motion plate), :mod:`~scenes.specimens.beam` (the
  bending beam as a speckled solid);
* any specimen from a mesh or FE result (the generic path): :mod:`~scenes.specimens.fe_files` (one reader per
  file type: STL/PLY/OBJ, meshio formats, ParaView ``.pvd``, Exodus II) -> :mod:`~scenes.specimens.surface_mesh`
  (curved FE faces, :mod:`~scenes.specimens.face_elements`) -> :mod:`~scenes.specimens.mesh_specimen` (states,
  surfaces to render, per-pixel truth), with :mod:`~scenes.specimens.ray_surface` (which material point a pixel
  sees, no renderer involved);
* :mod:`~scenes.specimens.catalog` -- specimens with their FE solutions, written as files a user could have made.

May import: ``scenes.deformation``, ``scenes.surfaces``, ``scenes.optics``, ``scenes._checks``. Never
``measurement/``.
"""
from scenes import _legacy

#: Names of the former flat module ``scenes.specimens``, kept for one release.
_MOVED = {"SpeckledPlate": "scenes.specimens.plate", "BendingSpecimen": "scenes.specimens.beam"}


def __getattr__(name):
    return _legacy.moved_name("scenes.specimens", _MOVED, name)
