"""The paper's experiments, one package each: ``calibration``, ``rigid_motion``, ``bending``, ``depth_of_field``,
``dic2d``, and ``paper`` (all of them in one report). In each, the scene builder (``scenes.py`` or ``views.py``)
computes the truth with ``scenes/`` only; ``run.py`` renders through the store, measures with ``measurement/``
and scores; ``case.py`` is the experiment as one study or gate case.
"""
