"""The one way from a scene to its images: every view rendered by the renderer that makes it with the least
Monte-Carlo noise, with a record of which renderer made it and why (truth side).

Every experiment, the specimen path, the twin and the studies render through :func:`render_views` (only the
sub-pixel study, :mod:`workbench.experiments.subpixel`, and the renderers' benchmarks call each renderer by name:
they test the renderers one by one). What it picks,
per scene (all views of one scene share one Mitsuba scene where Monte Carlo is needed):

* ``renderer="auto"`` (the default)

  - with ``mc_target_grey``: each view's pixels that need no sampling are made deterministically -- all of a
    pinhole view and the in-focus pixels of a thin lens (:func:`scenes.rendering.exact.render_view_in_focus`),
    surfaces that hide one another but at their occluding edges
    (:func:`scenes.rendering.exact.render_view_occluded`), the blurred faces of a thin lens by quadrature
    (:func:`scenes.rendering.defocus_quadrature.fill_defocused_faces`) -- and Mitsuba's adaptive renderer traces
    just the rest at that noise (:func:`scenes.rendering.adaptive.render_views_auto`);
  - without it: a view is made exactly where every view of the scene can be
    (:func:`scenes.rendering.exact.render_view_exact`: a pinhole, no occlusion), else Mitsuba renders each view
    whole at ``spp`` (:func:`scenes.rendering.mitsuba.render_view`) and the reason is recorded;

* ``renderer="exact"``: the exact renderer or :class:`scenes.rendering.exact.NotExactError` (naming the view);
* ``renderer="mitsuba"``: Monte Carlo only -- adaptive at ``mc_target_grey``, else ``spp`` samples per pixel;
* a photographed texture (:class:`scenes.surfaces.image_texture.TexturedPlane` in place of the surfaces): the
  photograph is point-sampled where each pixel's ray meets the plane (:func:`render_plane_view
  <scenes.surfaces.image_texture.render_plane_view>`): it already carries its camera's optics.

Seeds: Mitsuba's adaptive renders of a scene take ``seed``; a fixed-spp render of view ``c`` takes
``seed + c`` (or ``view_seeds[c]``): Monte-Carlo noise is pixel-locked, so views and states must not share it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.optics.camera import SensorSpec
from scenes.surfaces.image_texture import TexturedPlane, render_plane_view
from scenes.surfaces.textured_surface import TexturedSurface

#: The renderer choices of :func:`render_views`.
RENDERERS = ("auto", "exact", "mitsuba")
#: Name recorded for a photographed texture's view.
RENDERER_PHOTO = "photo-plane"
#: Names recorded for Mitsuba's renders.
RENDERER_MITSUBA = "mitsuba"
RENDERER_MITSUBA_ADAPTIVE = "mitsuba-adaptive"


@dataclass
class RenderedView:
    """One view of :func:`render_views`.

    Attributes
    ----------
    image_grey : ndarray (H, W)
        Grey levels before sensor noise.
    renderer : str
        Which renderer made it: :data:`scenes.rendering.exact.RENDERER` and its relatives, the thin-lens mixes of
        :mod:`scenes.rendering.defocus_quadrature`, :data:`RENDERER_MITSUBA`, :data:`RENDERER_MITSUBA_ADAPTIVE`,
        :data:`RENDERER_PHOTO`.
    reason : str or None
        Why Monte Carlo rendered the whole view where the deterministic renderers were asked first (the refusal
        of the view :attr:`reason_view`).
    reason_view : int or None
        Index of the view whose deterministic render was refused.
    known_fraction : float or None
        Share of the view's lit pixels made without Monte Carlo (``auto`` with ``mc_target_grey``).
    mc : dict or None
        The adaptive render's measured noise and sample counts
        (:func:`scenes.rendering.adaptive.render_views_adaptive`); None where Mitsuba traced nothing or rendered
        at a fixed spp.
    defocus_error_grey : float or None
        The largest RMS error of the thin-lens quadrature's rules against a denser rule, grey, where blurred faces
        were made by quadrature.
    valid : ndarray (H, W) bool or None
        Pixels that show the surface (a photographed texture's view).
    """

    image_grey: np.ndarray
    renderer: str
    reason: str | None = None
    reason_view: int | None = None
    known_fraction: float | None = None
    mc: dict | None = None
    defocus_error_grey: float | None = None
    valid: np.ndarray | None = None


def render_views(views: list[tuple[SensorSpec, tuple[np.ndarray, np.ndarray]]],
                 surfaces: list[TexturedSurface] | TexturedPlane, *, renderer: str = "auto", spp: int = 64,
                 seed: int = 0, view_seeds: list[int] | None = None, exposure_grey: float = 255.0,
                 mc_target_grey: float | None = None, settings=None,
                 displacement_mm=None) -> list[RenderedView]:
    """Every view of one scene, each by the renderer that makes it with the least Monte-Carlo noise.

    Parameters
    ----------
    views : list of ``(SensorSpec, (R_cam_from_world, t_cam_from_world_mm))``
    surfaces : the scene's :class:`~scenes.surfaces.textured_surface.TexturedSurface` list (world frame, mm), or
        one :class:`~scenes.surfaces.image_texture.TexturedPlane` (a photographed texture)
    renderer : one of :data:`RENDERERS` (see the module's docstring)
    spp : samples per pixel of a fixed-spp Mitsuba render (unused with ``mc_target_grey``)
    seed : the scene's Monte-Carlo seed; ``view_seeds``: per-view seeds of fixed-spp renders (default
        ``seed + c``)
    exposure_grey : grey level of a white (radiance 1) surface
    mc_target_grey : Monte-Carlo noise target of Mitsuba's adaptive renderer, grey RMS (None: fixed ``spp``)
    settings : :class:`scenes.rendering.adaptive.AdaptiveSettings` (default: the target alone)
    displacement_mm : a photographed plane's displacement field ``u(X_world_mm (N, 3)) -> (N, 3)`` (only with a
        :class:`TexturedPlane`)

    Returns
    -------
    list of :class:`RenderedView`, one per view, in order
    """
    if renderer not in RENDERERS:
        raise ValueError(f"renderer {renderer!r}: choose one of {', '.join(RENDERERS)}")
    if isinstance(surfaces, TexturedPlane):
        out = []
        for spec, pose in views:
            image, valid = render_plane_view(spec, pose, surfaces, displacement_mm)
            out.append(RenderedView(image, RENDERER_PHOTO, valid=valid))
        return out
    if displacement_mm is not None:
        raise ValueError("displacement_mm moves a photographed plane only; move a mesh's vertices instead")
    if mc_target_grey is not None and settings is None:
        from scenes.rendering.adaptive import AdaptiveSettings

        settings = AdaptiveSettings(target_mc_grey=mc_target_grey)
    if renderer == "auto" and mc_target_grey is not None:
        from scenes.rendering.adaptive import render_views_auto

        return [RenderedView(r.image_grey, r.renderer, reason=r.fallback, known_fraction=r.known_fraction, mc=r.mc,
                             defocus_error_grey=r.defocus_error_grey)
                for r in render_views_auto(views, surfaces, seed=seed, exposure_grey=exposure_grey,
                                           settings=settings)]
    reason = reason_view = None
    if renderer in ("auto", "exact"):
        from scenes.rendering.exact import NotExactError, render_view_exact

        exact = []
        for c, (spec, pose) in enumerate(views):
            try:
                exact.append(render_view_exact(spec, *pose, surfaces, exposure_grey=exposure_grey))
            except NotExactError as err:
                if renderer == "exact":
                    err.view_index = c
                    raise
                reason, reason_view = str(err), c
                break
        else:
            return [RenderedView(image, info["renderer"]) for image, info in exact]
    if mc_target_grey is not None:
        from scenes.rendering.adaptive import render_views_adaptive

        return [RenderedView(r.image_grey, RENDERER_MITSUBA_ADAPTIVE, reason=reason, reason_view=reason_view,
                             mc=r.mc)
                for r in render_views_adaptive(views, surfaces, seed=seed, exposure_grey=exposure_grey,
                                               settings=settings)]
    from scenes.rendering.mitsuba import render_view

    seeds = [seed + c for c in range(len(views))] if view_seeds is None else list(view_seeds)
    if len(seeds) != len(views):
        raise ValueError(f"view_seeds: one seed per view ({len(views)}), got {len(seeds)}")
    return [RenderedView(render_view(spec, *pose, surfaces, spp=spp, seed=s, exposure_grey=exposure_grey).image_grey,
                         RENDERER_MITSUBA, reason=reason, reason_view=reason_view)
            for (spec, pose), s in zip(views, seeds)]


__all__ = ["RENDERERS", "RENDERER_MITSUBA", "RENDERER_MITSUBA_ADAPTIVE", "RENDERER_PHOTO", "RenderedView",
           "render_views"]
