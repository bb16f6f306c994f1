"""Sensor and environment (truth side, floor 5 of ``scenes/``): what happens to an image after the optics.

* :mod:`~scenes.sensor.noise` -- shot and read noise, quantisation to the sensor's bit depth;
* :mod:`~scenes.sensor.illumination` -- illumination change between states;
* :mod:`~scenes.sensor.drift` -- camera drift between states (the camera is not where it was calibrated).

May import: the rooms below (``scenes.specimens`` ... ``scenes.optics``), ``scenes._checks``. Never
``measurement/``.
"""
