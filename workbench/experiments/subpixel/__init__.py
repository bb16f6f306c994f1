"""The truth below a pixel: is a rendered sub-pixel motion the exact image of the specimen moved (issue 38)?

A speckled plate faces a camera square on and moves rigidly in its plane by a fraction of a pixel. Every render
path draws it (:data:`PATHS`), and a *converged reference* of the same optical model draws it too: ``16 x 16``
sub-pixel rays per pixel, each meeting the plate, the paint evaluated at that point as what it is defined to be,
the band-limited interpolant of its pattern samples (:func:`scenes.surfaces.speckle.fourier_upsample` to at least 16 texels
per pixel, then looked up linearly, an error below 1e-5 px) -- not through the texture the renderers look up.

Two figures per path and phase, both by the instrument (2-D subset DIC, second order, biquintic):

* **render error** -- DIC between the reference and the render *of the same position*: any displacement it finds
  is the render's own, the pattern drawn where it is not (0 for an exact render; the instrument is not in it);
* **motion error** -- DIC between the render at rest and the render moved, minus the true motion, beside the
  instrument alone on the references (the exact images) at rest and moved.

Without sensor noise both are systematic: what the DIC finds is what the images carry. Also here: the twin's
photographed texture against the exact (Fourier) shift of a periodic photograph (:func:`photo_phase_errors`), and
speckle aliasing as an error source, through the lens' diffraction (:func:`aliasing_study`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from scenes.optics.camera import SensorSpec
from scenes.surfaces.paint import Paint, layout, pattern, texture
from scenes.surfaces.speckle import fourier_upsample
from scenes.surfaces.textured_surface import TexturedSurface
from scenes.optics.projection import focal_length_for_focus_mm, pixel_rays

#: Render paths checked (``pinhole`` quadrature, the occlusion renderer, a thin lens in focus, Mitsuba).
PATHS = ("quadrature", "occlusion", "thin lens in focus", "mitsuba")
#: Sub-pixel rays per pixel side of the converged reference.
REFERENCE_SIDE = 16
#: Pixels along the image's edges no subset reaches (a path may leave them to Monte Carlo).
EDGE_PX = 4
#: Texels per pixel of the reference's band-limited paint (its linear lookup errs by < 1e-5 px there).
REFERENCE_TEXELS_PER_PX = 16.0


@dataclass(frozen=True)
class PlateScene:
    """A square camera (pinhole or thin lens) facing a painted plate at ``distance_mm``, camera frame = world.

    ``size_px`` pixels a side; the plate covers them with a margin. The paint's speckle is ``speckle_px`` at the
    plate. ``texel_px`` is the pattern's sample spacing (None: the paint's default, speckle / 5); ``lookup_factor``
    overrides the paint's (1: the pattern itself is looked up, as before issue 38; with ``texel_px = 1 / 3.5`` that
    is the paper's planar specimens' texture, :meth:`scenes.specimens.beam.BendingSpecimen.for_pixel_size`). ``edge_px``:
    the speckles' edge width (None: speckle / 6; the pattern is then sampled at ``min(speckle / 5, 2 edge)``);
    ``f_number``: the lens' diffraction on pixels of ``pixel_pitch_mm`` (None: ideal optics), the view rendered
    ``supersample`` times finer first (:func:`render`)."""

    size_px: int = 96
    fx_px: float = 8000.0
    distance_mm: float = 300.0
    speckle_px: float = 5.0
    seed: int = 0
    lookup_factor: int | None = None
    texel_px: float | None = None
    alpha_deg: float = 0.0
    k1: float = 0.0
    edge_px: float | None = None
    f_number: float | None = None
    supersample: int = 1
    pixel_pitch_mm: float = 0.00345

    @property
    def optics(self):
        from scenes.optics.mtf import Optics

        return Optics(f_number=self.f_number, pixel_pitch_mm=self.pixel_pitch_mm)

    @property
    def footprint_mm(self) -> float:
        return self.distance_mm / self.fx_px

    def spec(self, lens: str = "pinhole") -> SensorSpec:
        c = (self.size_px - 1) / 2.0
        spec = SensorSpec(fx=self.fx_px, fy=self.fx_px, cx=c, cy=c, width=self.size_px, height=self.size_px,
                          alpha_deg=self.alpha_deg, k1=self.k1)
        if lens == "pinhole":
            return spec
        thin = replace(spec, lens="thin", f_number=8.0, focal_length_mm=0.5 * spec.fx * spec.pixel_pitch_mm)
        F = focal_length_for_focus_mm(thin, np.eye(3), np.zeros(3), [[0.0, 0.0, self.distance_mm]])
        return replace(thin, focal_length_mm=F)

    def paint(self) -> Paint:
        texel_px = self.texel_px
        if texel_px is None and self.edge_px is not None:
            texel_px = min(self.speckle_px / 5.0, 2.0 * self.edge_px)
        texel = None if texel_px is None else texel_px * self.footprint_mm
        edge = None if self.edge_px is None else self.edge_px * self.footprint_mm
        return Paint(speckle_mm=self.speckle_px * self.footprint_mm, texel_mm=texel, edge_mm=edge, seed=self.seed)

    def plate(self):
        """(vertices (4, 3) mm at rest, faces, paint layout) of the plate, 30 % larger than the view."""
        h = 0.65 * self.size_px * self.footprint_mm
        V = np.array([[-h, -h, self.distance_mm], [h, -h, self.distance_mm], [h, h, self.distance_mm],
                      [-h, h, self.distance_mm]])
        T = np.array([[0, 2, 1], [0, 3, 2]])              # normal -z: faces the camera
        return V, T, layout(self.paint(), V, T, "subpixel plate")

    def surfaces(self, offset_px=(0.0, 0.0)) -> list[TexturedSurface]:
        """The plate moved in its plane by ``offset_px`` (x, y) pixels' worth of footprint."""
        V, T, lay = self.plate()
        paint = self.paint()
        if self.lookup_factor is not None:
            tex = fourier_upsample(pattern(paint, lay.shape), self.lookup_factor)
        else:
            tex = texture(paint, lay.shape, lay.origin_mm)
        move = np.array([offset_px[0], offset_px[1], 0.0]) * self.footprint_mm
        return [TexturedSurface(vertices_mm=V + move, faces=T, uv=lay.uv(), texture=tex, filter="bilinear")]


def converged_reference(scene: PlateScene, offset_px=(0.0, 0.0), exposure_grey: float = 255.0,
                        side: int = REFERENCE_SIDE) -> np.ndarray:
    """The box-filtered pinhole image of the plate moved by ``offset_px``, from ``side**2`` rays per pixel and the
    paint's band-limited interpolant (module docstring). Returns (size_px, size_px) float64 grey levels."""
    V, T, lay = scene.plate()
    pat = pattern(scene.paint(), lay.shape)
    texel_px = lay.size_mm[0] / lay.shape[1] / scene.footprint_mm
    factor = int(np.ceil(REFERENCE_TEXELS_PER_PX * texel_px))
    fine = fourier_upsample(pat, factor).astype(np.float64)
    spec = scene.spec("pinhole")
    n = scene.size_px
    sub = (np.arange(side) + 0.5) / side - 0.5
    out = np.zeros((n, n))
    move = np.array([offset_px[0], offset_px[1]]) * scene.footprint_mm
    from scipy.ndimage import map_coordinates

    for row in range(n):                       # one image row at a time: side**2 * n rays
        xs = (np.arange(n)[:, None] + sub[None, :]).ravel()
        ys = row + sub
        px = np.column_stack([np.tile(xs, side), np.repeat(ys, len(xs))])
        O, D = pixel_rays(spec, np.eye(3), np.zeros(3), px)
        X = O + D * ((scene.distance_mm - O[:, 2]) / D[:, 2])[:, None]
        uv = (X[:, :2] - move - lay.origin_mm) / lay.size_mm
        coords = [uv[:, 1] * fine.shape[0] - 0.5, uv[:, 0] * fine.shape[1] - 0.5]
        vals = map_coordinates(fine, coords, order=1, mode="grid-wrap")
        out[row] = vals.reshape(side, n, side).mean(axis=(0, 2))
    return exposure_grey * out


def render(scene: PlateScene, path: str, offset_px=(0.0, 0.0), *, exposure_grey: float = 255.0,
           mitsuba_target_grey: float = 0.05, seed: int = 1, quadrature_order: int | None = None) -> np.ndarray:
    """The plate moved by ``offset_px`` drawn by one of :data:`PATHS`; (size_px, size_px) float64 grey levels.
    ``quadrature_order`` overrides the deterministic paths' Gauss-Legendre nodes per pixel side. Raises ValueError
    when a deterministic path leaves a pixel of the view unknown."""
    from scenes.rendering.adaptive import AdaptiveSettings, render_views_adaptive
    from scenes.rendering.exact import render_view_exact, render_view_in_focus, render_view_occluded

    from scenes.rendering.exact import QUADRATURE_ORDER

    surfaces = scene.surfaces(offset_px)
    pose = (np.eye(3), np.zeros(3))
    q = {"exposure_grey": exposure_grey, "quadrature_order": quadrature_order or QUADRATURE_ORDER}
    s = scene.supersample

    def recorded(image):
        return scene.optics.apply(image, s) if (s > 1 or scene.f_number is not None) else image.astype(float)

    if path == "quadrature":
        return recorded(render_view_exact(scene.spec().supersampled(s), *pose, surfaces, **q)[0])
    if path == "occlusion":
        image, known, _ = render_view_occluded(scene.spec().supersampled(s), *pose, surfaces, **q)
    elif path == "thin lens in focus":
        image, known, _ = render_view_in_focus(scene.spec("thin").supersampled(s), *pose, surfaces, **q)
    elif path == "mitsuba":
        return recorded(render_views_adaptive([(scene.spec().supersampled(s), pose)], surfaces, seed=seed,
                                              exposure_grey=exposure_grey,
                                              settings=AdaptiveSettings(target_mc_grey=mitsuba_target_grey))[0]
                        .image_grey)
    else:
        raise ValueError(f"render path {path!r}: choose one of {', '.join(PATHS)}")
    e = EDGE_PX * s
    inner = known[e:-e, e:-e]
    if not inner.all():
        raise ValueError(f"the {path} path left {int((~inner).sum())} pixels of the plate's view to Monte Carlo")
    # The image's outermost pixels, which no subset reaches, take their nearest known neighbour's value: a jump to
    # 0 there would reach into the subsets through the B-spline prefilter.
    from scipy.ndimage import distance_transform_edt

    _, (r, c) = distance_transform_edt(~known, return_indices=True)
    return recorded(image.astype(float)[r, c])


def dic_displacements(reference: np.ndarray, deformed: np.ndarray, subset_px: int = 25, step_px: int = 6,
                      margin_px: int = 16, points: bool = False):
    """(N, 2) displacements (u, v) px the instrument measures from ``reference`` to ``deformed`` (second order,
    biquintic) at the converged points of a grid ``margin_px`` inside the image; with ``points`` also their (N, 2)
    positions (x, y) px, first."""
    from measurement.dic import DICSettings, correlate

    n = reference.shape[0]
    result = correlate(reference, deformed, DICSettings(subset_size=subset_px, step=step_px, order=2),
                       roi=(margin_px, margin_px, n - 1 - margin_px, n - 1 - margin_px))
    ok = np.isfinite(result.u) & np.isfinite(result.v)
    d = np.column_stack([result.u[ok], result.v[ok]])
    return (np.column_stack([result.x[ok], result.y[ok]]).astype(float), d) if points else d


def true_motion_px(scene: PlateScene, xy_px: np.ndarray, offset_px) -> np.ndarray:
    """(N, 2) image motion of the plate's points seen at ``xy_px`` when it moves by ``offset_px`` footprints: the
    ray meets the plate, the point moves, and is projected again (not uniform under a tilted sensor or a lens
    distortion)."""
    from scenes.optics.projection import project_points

    spec = scene.spec("pinhole")
    O, D = pixel_rays(spec, np.eye(3), np.zeros(3), xy_px)
    X = O + D * ((scene.distance_mm - O[:, 2]) / D[:, 2])[:, None]
    X[:, :2] += np.asarray(offset_px, float) * scene.footprint_mm
    return project_points(spec, np.eye(3), np.zeros(3), X) - xy_px


def phase_errors(scene: PlateScene, path: str, phases_px, *, reference_side: int = REFERENCE_SIDE,
                 **render_options) -> list[dict]:
    """For each (x, y) phase: the render error (DIC reference -> render of the same position: RMS and mean of
    |d|, px), the motion error (DIC render at rest -> render moved, minus the motion) and the instrument alone
    (the same on the references), against :func:`true_motion_px`. Both renders of a phase are one path's;
    ``render_options`` go to :func:`render`."""
    if scene.f_number is not None:
        raise ValueError("phase_errors: the converged reference has ideal optics; use motion_errors for a scene "
                         "with a diffraction")
    ref0 = converged_reference(scene, (0.0, 0.0), side=reference_side)
    img0 = render(scene, path, (0.0, 0.0), **render_options)
    rows = []
    for phase in phases_px:
        phase = (float(phase[0]), float(phase[1]))
        ref = converged_reference(scene, phase, side=reference_side) if phase != (0.0, 0.0) else ref0
        img = render(scene, path, phase, **render_options) if phase != (0.0, 0.0) else img0
        d_render = dic_displacements(ref, img)
        xy, d_motion = dic_displacements(img0, img, points=True)
        d_motion = d_motion - true_motion_px(scene, xy, phase)
        xy, d_alone = dic_displacements(ref0, ref, points=True)
        d_alone = d_alone - true_motion_px(scene, xy, phase)
        rows.append({"phase_px": list(phase),
                     "render_rms_px": _rms(d_render), "render_mean_px": d_render.mean(axis=0).tolist(),
                     "motion_rms_px": _rms(d_motion), "motion_mean_px": d_motion.mean(axis=0).tolist(),
                     "instrument_alone_rms_px": _rms(d_alone), "points": int(len(d_render)),
                     "grey_rms_vs_reference": float(np.sqrt(np.mean((img - ref)[8:-8, 8:-8] ** 2)))})
    return rows


def motion_errors(scene: PlateScene, path: str, phases_px, **render_options) -> list[dict]:
    """For each (x, y) phase: the motion error alone (DIC from the render at rest to the render moved, minus
    :func:`true_motion_px`): RMS, mean (px) and the points; any optics (no converged reference needed)."""
    img0 = render(scene, path, (0.0, 0.0), **render_options)
    rows = []
    for phase in phases_px:
        phase = (float(phase[0]), float(phase[1]))
        img = render(scene, path, phase, **render_options) if phase != (0.0, 0.0) else img0
        xy, d = dic_displacements(img0, img, points=True)
        d = d - true_motion_px(scene, xy, phase)
        rows.append({"phase_px": list(phase), "motion_rms_px": _rms(d), "motion_mean_px": d.mean(axis=0).tolist(),
                     "points": int(len(d))})
    return rows


def aliasing_study(speckles_px=(2.0, 3.0, 5.0), edges=("soft", "sharp"), f_numbers=(None, 4.0, 8.0, 16.0),
                   phases_px=None, supersample: int = 4, sharp_edge_px: float = 0.1, size_px: int = 96) -> list[dict]:
    """Speckle aliasing as an error source: the motion error (noise-free, quadrature, :func:`motion_errors`) of a
    plate moved by k/8 px along x and (0.5, 0.5), per speckle size, paint edge (``"soft"``: speckle / 6;
    ``"sharp"``: ``sharp_edge_px``) and f-number (None: ideal optics; diffraction at 550 nm on 3.45 um pixels),
    rendered ``supersample`` times finer so the optics act before the pixels sample. Returns one row per case with
    the worst RMS over the phases and the largest |mean| (the S-curve's amplitude)."""
    phases_px = phases_px or [(k / 8.0, 0.0) for k in range(1, 8)] + [(0.5, 0.5)]
    out = []
    for speckle in speckles_px:
        for edge in edges:
            for f_number in f_numbers:
                scene = PlateScene(size_px=size_px, speckle_px=float(speckle), f_number=f_number,
                                   supersample=supersample, edge_px=sharp_edge_px if edge == "sharp" else None)
                rows = motion_errors(scene, "quadrature", phases_px)
                out.append({"speckle_px": float(speckle), "edge": edge, "f_number": f_number,
                            "airy_radius_px": scene.optics.airy_radius_px,
                            "worst_rms_px": max(r["motion_rms_px"] for r in rows),
                            "worst_mean_px": max(max(abs(v) for v in r["motion_mean_px"]) for r in rows),
                            "rows": rows})
    return out


def _rms(d: np.ndarray) -> float:
    """RMS length of (N, 2) vectors."""
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))) if len(d) else float("nan")





# ---- the twin's photographed texture ------------------------------------------------------------------------
def fourier_shift(image: np.ndarray, shift_px) -> np.ndarray:
    """A periodic image moved by ``shift_px`` (x, y) exactly as a band-limited function (Nyquist terms left out):
    the value at ``(x, y)`` is the original's at ``(x - sx, y - sy)``."""
    rows, cols = image.shape
    fy = np.fft.fftfreq(rows)
    fx = np.fft.fftfreq(cols)
    spectrum = np.fft.fft2(image)
    spectrum[np.abs(fy) >= 0.5, :] = 0
    spectrum[:, np.abs(fx) >= 0.5] = 0
    phase = np.exp(-2j * np.pi * (fy[:, None] * shift_px[1] + fx[None, :] * shift_px[0]))
    return np.fft.ifft2(spectrum * phase).real


def photo_phase_errors(photo: np.ndarray, phases_px, margin_px: int = 24) -> list[dict]:
    """The twin's path (:func:`scenes.surfaces.image_texture.render_deformed_image`: a photograph read as a continuous
    texture and moved): for a *periodic* photo, whose exact sub-pixel motion is its band-limited shift
    (:func:`fourier_shift`), the render error (DIC from the exact shift to the twin's image) and the motion error
    (DIC from the photo to the twin's moved image, minus the motion) beside the instrument alone, per phase, on
    points ``margin_px`` inside the image (the texture's mirror boundary errs at its edges)."""
    from scenes.surfaces.image_texture import ImageTexture, render_deformed_image

    texture = ImageTexture.from_image(photo)
    rows = []
    for phase in phases_px:
        phase = (float(phase[0]), float(phase[1]))
        exact = fourier_shift(photo, phase)
        twin, _ = render_deformed_image(texture, lambda X, Y: (np.full_like(X, phase[0]), np.full_like(Y, phase[1])))
        d_render = dic_displacements(exact, twin, margin_px=margin_px)
        d_motion = dic_displacements(photo, twin, margin_px=margin_px) - np.array(phase)
        d_alone = dic_displacements(photo, exact, margin_px=margin_px) - np.array(phase)
        rows.append({"phase_px": list(phase), "render_rms_px": _rms(d_render),
                     "render_mean_px": d_render.mean(axis=0).tolist(), "motion_rms_px": _rms(d_motion),
                     "motion_mean_px": d_motion.mean(axis=0).tolist(), "instrument_alone_rms_px": _rms(d_alone),
                     "points": int(len(d_render))})
    return rows

__all__ = ["PATHS", "PlateScene", "converged_reference", "aliasing_study", "dic_displacements", "fourier_shift",
           "motion_errors", "phase_errors", "photo_phase_errors", "render", "true_motion_px"]
