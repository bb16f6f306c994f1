"""The truth side: scenes rendered through our Scheimpflug cameras, with the exact truth of every pixel.

Rooms, lowest first; a room imports only from rooms below it (``tests/test_architecture.py``), and none imports
``measurement/`` (the instrument) or ``workbench/``:

1. :mod:`scenes.optics` -- the camera: Mitsuba sensor plugin, backend, geometric truth of a pixel, lens MTF;
2. :mod:`scenes.surfaces` -- textured meshes, speckle, paint, calibration targets, photographed textures;
3. :mod:`scenes.deformation` -- displacement fields, stage motions, the beam's finite-element solution;
4. :mod:`scenes.specimens` -- the plate and the beam, any specimen from a mesh or FE file, the catalog;
5. :mod:`scenes.sensor` -- noise, illumination change, camera drift;
6. :mod:`scenes.rendering` -- one entry (:func:`scenes.rendering.render.render_views`) over the exact, quadrature,
   occlusion-aware and Monte-Carlo renderers;
7. :mod:`scenes.image_pairs` -- exact 2-D pairs for a 2-D DIC engine (Gaussian speckle, Fourier shift, Star).

``scenes._checks`` holds the argument checks every room shares. The flat module paths of earlier releases
(``scenes.truth``, ``scenes.fields``, ...) still import, with a DeprecationWarning (:mod:`scenes._legacy`).
"""
from scenes import _legacy

_legacy.install()
