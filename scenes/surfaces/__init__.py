"""Surfaces and paint (truth side, floor 2 of ``scenes/``): what a renderer draws and what is painted on it.

* :mod:`~scenes.surfaces.textured_surface` -- the emissive textured triangle mesh every rendered object is;
* :mod:`~scenes.surfaces.speckle` -- random speckle patterns; :mod:`~scenes.surfaces.paint` -- paint (speckle or
  checker) laid on a specimen's surface with its size in mm;
* calibration targets: :mod:`~scenes.surfaces.checkerboard` (the paper's, with print and flatness
  imperfections), :mod:`~scenes.surfaces.charuco`, :mod:`~scenes.surfaces.dot_grid`;
* :mod:`~scenes.surfaces.image_texture` -- a photographed speckle image as a texture (the twin's scenes).

May import: ``scenes.optics``, ``scenes._checks``. Never ``measurement/``.
"""
from scenes import _legacy

#: Names of the former flat module ``scenes.surfaces`` (now :mod:`scenes.surfaces.textured_surface`).
_MOVED = {"TexturedSurface": "scenes.surfaces.textured_surface"}


def __getattr__(name):
    return _legacy.moved_name("scenes.surfaces", _MOVED, name)
