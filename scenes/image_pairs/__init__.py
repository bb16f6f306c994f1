"""2-D image pairs (truth side, floor 7 of ``scenes/``): exact pairs for a 2-D DIC engine, no camera, no renderer.

* :mod:`~scenes.image_pairs.analytic_fields` -- analytic displacement fields in px (translation, homogeneous
  strain, rotation, quadratic) and the inversion ``x = X + u(X)``;
* :mod:`~scenes.image_pairs.gaussian_speckle` -- analytic Gaussian speckle sampled exactly at any point;
* :mod:`~scenes.image_pairs.fourier_shift` -- exact sub-pixel translations by Fourier shifting;
* :mod:`~scenes.image_pairs.star` -- the DIC Challenge 2.0 "Star" pairs.

May import: every room below, ``scenes._checks``. Never ``measurement/``.
"""
