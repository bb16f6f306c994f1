"""Optics of a camera (truth side, floor 1 of ``scenes/``): what a camera is and where each pixel looks.

* :mod:`~scenes.optics.camera` -- the Scheimpflug (tilted-sensor) camera as a Mitsuba sensor plugin: pinhole or
  thin lens, lens distortion (:class:`~scenes.optics.camera.SensorSpec`);
* :mod:`~scenes.optics.backend` -- the one place that chooses and starts Mitsuba's variant;
* :mod:`~scenes.optics.projection` -- the exact geometric truth of a pixel without rendering: projection, pixel
  rays, the plane of sharp focus, defocus blur, front-face intersections;
* :mod:`~scenes.optics.mtf` -- what a real lens and pixel add to an image: diffraction, pixel aperture, a sensor MTF.

May import: ``scenes._checks`` only (it is the lowest room). Never ``measurement/``.
"""
from scenes import _legacy

#: Names of the former flat module ``scenes.optics`` (now :mod:`scenes.optics.mtf`), kept for one release.
_MOVED = {name: "scenes.optics.mtf" for name in (
    "DEFAULT_WAVELENGTH_NM", "Optics", "airy_radius_px", "apply_optics", "cutoff_cycles_per_px", "diffraction_otf",
    "aperture_otf", "pixel_aperture_gain", "mtf_from_table")}


def __getattr__(name):
    return _legacy.moved_name("scenes.optics", _MOVED, name)
