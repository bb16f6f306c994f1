"""Deformation and motion (truth side, floor 3 of ``scenes/``): how a specimen's material points move.

* :mod:`~scenes.deformation.displacement_field` -- the interface every field implements (``u(X)`` and its
  gradient, mm, specimen frame) and the simple fields: rigid motion, scaled, difference;
* :mod:`~scenes.deformation.stage` -- the paper's rigid stage translations, with stage errors;
* :mod:`~scenes.deformation.beam_bending` -- the paper's beam in three-point bending, solved by finite elements
  (scikit-fem), with beam theory to compare;
* :mod:`~scenes.deformation.fe_elements` -- the reference volume elements (node order, shape functions) the
  solver writes and a user's FE file is read with.

A user's FE result is read as a specimen (:mod:`scenes.specimens.fe_files`), not here: one FE path.

May import: ``scenes.surfaces``, ``scenes.optics``, ``scenes._checks``. Never ``measurement/``.
"""
