"""Rendering (truth side, floor 6 of ``scenes/``): from surfaces and cameras to images.

One entry, :func:`scenes.rendering.render.render_views`, picks per view the renderer that makes it exactly or
at the least Monte-Carlo noise, and records which and why:

* :mod:`~scenes.rendering.exact` -- pinhole views without sampling (exact coverage, Gauss-Legendre quadrature of
  the paint), the in-focus pixels of a thin lens, occlusion-aware views;
* :mod:`~scenes.rendering.defocus_quadrature` -- thin-lens pixels of flat faces by quadrature (rules:
  :mod:`~scenes.rendering.defocus_rules`), of smooth meshes by walking each ray (:mod:`~scenes.rendering.defocus_mesh`);
* :mod:`~scenes.rendering.adaptive` -- Mitsuba, adaptively sampled, for what is left (blurred silhouettes);
* :mod:`~scenes.rendering.mitsuba` -- plain Mitsuba at a fixed sample count (:mod:`~scenes.rendering.integrator`:
  the integrator with truth channels);
* the rasterisers they share: :mod:`~scenes.rendering.coverage_raster`, :mod:`~scenes.rendering.quadrature_raster`,
  :mod:`~scenes.rendering.thin_lens_rays`.

May import: every room below (``scenes.sensor`` ... ``scenes.optics``), ``scenes._checks``. Never ``measurement/``.
"""
