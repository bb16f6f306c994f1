"""A digital twin of the user's own rig: what it will measure, before the test (``workbench twin``).

From the user's calibration file and images the twin reads their speckle (histogram, contrast, speckle size,
SSSIG and MIG per subset, saturation) and each camera's noise (measured from a static pair, else estimated from
one image), paints their photographed pattern on a plane in front of their rig, renders it through their
cameras with their noise, and runs the instrument on it: the static noise floor of U, V, W (µm) and of strain
(µε) per point and pooled, the instrument's own predicted sigma beside it (:mod:`measurement.uncertainty`, with
their noise), the interpolation bias and the spatial resolution (l10) on their pattern, and a ranked what-if table
of subset, step, order and strain window. With a real static pair the same instrument measures it, and both
predictions are compared with it.

Python API::

    from workbench.twin import run_twin, TwinSettings, write_twin_report
    result = run_twin("L0.tif", "R0.tif", "L1.tif", "R1.tif", calibration="cal.xml",
                      settings=TwinSettings(subset_px=33, step_px=8, order=2, strain_window=5))
    result.prediction["noise"]            # {"U_um": ..., "V_um": ..., "W_um": ...}
    write_twin_report(result, "twin/")    # report.html, report.md, twin.json, maps

Modules: :mod:`.inputs` (reading and refusing), :mod:`.scene` (the twin's images), :mod:`.measure` (the
instrument on a static pair), :mod:`.predict`, :mod:`.whatif`, :mod:`.run`, :mod:`.report`.
"""
from .inputs import TwinInputs, load_inputs
from .measure import StaticNoise, static_noise_2d, static_noise_stereo
from .report import write_twin_report
from .run import NotStaticError, TwinResult, TwinSettings, run_twin

__all__ = ["NotStaticError", "StaticNoise", "TwinInputs", "TwinResult", "TwinSettings", "load_inputs", "run_twin",
           "static_noise_2d", "static_noise_stereo", "write_twin_report"]
