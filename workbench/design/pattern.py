"""The instrument's match uncertainty on a speckle image of a given size and blur, tabulated for the designer.

A candidate rig is judged before any image exists, so the designer cannot run the instrument on the rig's own
images; it runs it on small synthetic images of the same paint instead. For each speckle diameter ``s`` (px in the
image), defocus blur circle ``c`` (diameter, px: the thin lens' uniform disc) and diffraction ``g`` (the Airy
pattern's Gaussian-equivalent sigma ``0.42 lambda N``, px) an image of the paint is made as the renderer makes it
(:func:`paint_images`: the paint's samples and their band-limited interpolant, blurred by the disc and the Airy
pattern, box-averaged over each pixel) at a fixed exposure ``E0`` and the instrument's own estimator,
:func:`measurement.uncertainty.match.reference_subsets` (the IC-GN Hessian and the image noise), gives the
covariance of (u, v) per unit noise variance, averaged over the image's subsets. One table per subset size, shape
function order and paint; the designer reads it at each ROI point of each candidate (trilinear in log s, c, g) and
scales it by the candidate's noise and exposure: ``Cov = sigma_n^2 (E0 / E)^2 T(s, c, g)`` (the Hessian grows with the
square of the exposure, the noise term with the noise variance). Also tabulated: the interpolant's mean noise gain
``kappa`` over sub-pixel phases (what a target image sampled at a random phase adds, relative to whole pixels) and
the mean intensity gradient (MIG, Pan et al. 2010) per unit exposure.

One implementation: the numbers are the instrument's (:mod:`measurement.uncertainty.match`), only the images are
synthetic, so the design predicts what ``workbench stereo`` will report on the built rig.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from measurement.image_quality import mean_intensity_gradient
from measurement.speckle_quality import NoiseModel
from measurement.uncertainty.match import reference_subsets
from scenes.optics.mtf import aperture_otf
from scenes.surfaces.speckle import speckle_pattern

#: Airy pattern's best-fitting Gaussian: sigma = AIRY_SIGMA lambda N (image plane). The table's diffraction axis is
#: that sigma in px; the images get the Airy pattern itself (:func:`paint_images`).
AIRY_SIGMA = 0.42

#: Exposure of the table's images: grey of paint value 1, so high that unit noise leaves the Hessian noise-free (the
#: noise enters only through the scaling, module notes).
E0_GREY = 1.0e6
#: Oversampling of the paint before the pixels average it.
OVERSAMPLE = 4
#: Speckle diameters (px), defocus blur-circle diameters (px) and diffraction sigmas (px) of the table. A uniform
#: disc is not a Gaussian of the same second moment (c / 4): on a 4 px speckle a 6 px disc leaves ~10 % less
#: gradient energy than that Gaussian (measured on the renders of a design's untilted rig).
SPECKLE_PX = tuple(float(v) for v in np.geomspace(1.5, 32.0, 10))
DEFOCUS_PX = (0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 18.0, 28.0)
DIFFRACTION_PX = (0.0, 0.3, 0.6, 1.2)


@dataclass(frozen=True)
class PatternTable:
    """The instrument's (u, v) covariance on the paint, per unit noise variance at exposure :data:`E0_GREY`.

    Attributes
    ----------
    speckle_px, defocus_px, diffraction_px : ndarray (S,), (C,), (G,)
    cov_px2 : ndarray (S, C, G)
        Mean over subsets of ``(Cov_uu + Cov_vv) / 2`` (the texture is isotropic), px^2 per grey^2.
    kappa : ndarray (S, C, G)
        Mean over sub-pixel phases of the interpolant's gain on the noise a target image adds (<= 1).
    mig_per_exposure : ndarray (S, C, G)
        Mean intensity gradient of the image per unit exposure (grey/px per grey).
    subset_px, order : int
    contrast, density : float
    """

    speckle_px: np.ndarray
    defocus_px: np.ndarray
    diffraction_px: np.ndarray
    cov_px2: np.ndarray = field(repr=False)
    kappa: np.ndarray = field(repr=False)
    mig_per_exposure: np.ndarray = field(repr=False)
    subset_px: int = 33
    order: int = 1
    contrast: float = 0.8
    density: float = 0.5

    @staticmethod
    def _axis(grid: np.ndarray, value, log: bool):
        v = np.clip(np.asarray(value, float), grid[0], grid[-1])
        g = np.log(grid) if log else grid
        x = np.log(v) if log else v
        i = np.clip(np.searchsorted(g, x) - 1, 0, g.size - 2)
        return i, (x - g[i]) / (g[i + 1] - g[i])

    def _interp(self, table: np.ndarray, speckle_px, defocus_px, diffraction_px, log: bool) -> np.ndarray:
        i, a = self._axis(self.speckle_px, speckle_px, True)
        j, b = self._axis(self.defocus_px, defocus_px, False)
        k, c = self._axis(self.diffraction_px, diffraction_px, False)
        t = np.log(table) if log else table
        out = 0.0
        for di, wi in ((0, 1 - a), (1, a)):
            for dj, wj in ((0, 1 - b), (1, b)):
                for dk, wk in ((0, 1 - c), (1, c)):
                    out = out + wi * wj * wk * t[i + di, j + dj, k + dk]
        return np.exp(out) if log else out

    def covariance(self, speckle_px, defocus_px, diffraction_px) -> np.ndarray:
        """Tabulated (u, v) variance per unit noise variance at E0, px^2/grey^2 (trilinear, log in s and value)."""
        return self._interp(self.cov_px2, speckle_px, defocus_px, diffraction_px, log=True)

    def noise_gain(self, speckle_px, defocus_px, diffraction_px) -> np.ndarray:
        return self._interp(self.kappa, speckle_px, defocus_px, diffraction_px, log=False)

    def mig(self, speckle_px, defocus_px, diffraction_px) -> np.ndarray:
        return self._interp(self.mig_per_exposure, speckle_px, defocus_px, diffraction_px, log=True)

    def out_of_range(self, speckle_px, defocus_px, diffraction_px) -> np.ndarray:
        """Where a lookup was clipped to the table's edge (the prediction is extrapolated there)."""
        s = np.asarray(speckle_px, float)
        return ((s < self.speckle_px[0]) | (s > self.speckle_px[-1]) | (np.asarray(defocus_px) > self.defocus_px[-1])
                | (np.asarray(diffraction_px) > self.diffraction_px[-1]))


#: Texels per speckle diameter of a paint's samples (:attr:`scenes.surfaces.paint.Paint.texel`: speckle / 5).
PAINT_TEXELS_PER_SPECKLE = 5.0


def _disc_transfer(f: np.ndarray, diameter: float) -> np.ndarray:
    """Fourier transform of a uniform disc of ``diameter`` (samples) at radial frequencies ``f`` (cycles/sample)."""
    from scipy.special import j1

    x = np.pi * diameter * f
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(x > 1e-12, 2.0 * j1(x) / np.where(x > 1e-12, x, 1.0), 1.0)


def paint_images(speckle_px: float, blurs, size_px: int, *, contrast: float = 0.8, density: float = 0.5,
                 seed: int = 0) -> list[np.ndarray]:
    """Images (size_px square) of the paint with speckle ``speckle_px``, one per ``(defocus_px, diffraction_px)`` of
    ``blurs``, as the renderer makes them.

    The paint is what :mod:`scenes.surfaces.paint` renders: the speckle's samples at ``speckle / 5`` texels
    (:func:`scenes.surfaces.speckle.speckle_pattern`, the paint's soft edge) and their band-limited (Fourier) interpolant;
    here that interpolant is evaluated on a grid :data:`OVERSAMPLE` (or more) times finer than the pixels, blurred
    by a uniform disc of the defocus diameter and the lens' Airy pattern (:func:`scenes.optics.mtf.aperture_otf`, the
    renderer's own; ``diffraction_px`` is its Gaussian-equivalent sigma :data:`AIRY_SIGMA` ``lambda N``), and
    averaged over each pixel. The texel count is rounded so that the periodic pattern spans the patch exactly (the speckle is then
    ``5 size / round(5 size / speckle)`` px, within 1 %).
    """
    texels = max(8, int(round(PAINT_TEXELS_PER_SPECKLE * size_px / speckle_px)))
    samples = speckle_pattern((texels, texels), PAINT_TEXELS_PER_SPECKLE, density=density, contrast=contrast,
                              mean=0.5, seed=seed).astype(np.float64)
    over = max(OVERSAMPLE, int(np.ceil(texels / size_px)) + 1)
    n = size_px * over
    spectrum = np.fft.fft2(samples)
    k = np.round(np.fft.fftfreq(texels) * texels).astype(int)
    if texels % 2 == 0:                      # split the Nyquist row/column: the interpolant stays real
        spectrum[texels // 2, :] *= 0.5
        spectrum[:, texels // 2] *= 0.5
        spectrum = np.concatenate([spectrum, spectrum[texels // 2:texels // 2 + 1, :]], axis=0)
        spectrum = np.concatenate([spectrum, spectrum[:, texels // 2:texels // 2 + 1]], axis=1)
        k = np.concatenate([k, [texels // 2]])
    fine = np.zeros((n, n), complex)
    fine[np.ix_(k % n, k % n)] += spectrum
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.fftfreq(n)[None, :]
    radial = np.sqrt(fx ** 2 + fy ** 2)
    out = []
    for defocus, diffraction in blurs:
        # the lens' diffraction as the renderer applies it (scenes.optics.mtf: the aperture's Airy OTF, cut-off
        # 1 / (lambda N) = AIRY_SIGMA / diffraction cycles per px); its Gaussian of the same sigma keeps ~10 % more
        # gradient energy at f/8 on a 4 px speckle
        airy = aperture_otf(radial * over * diffraction / AIRY_SIGMA) if diffraction > 0 else 1.0
        transfer = _disc_transfer(radial, defocus * over) * airy
        image = np.fft.ifft2(fine * transfer).real * (n * n) / (texels * texels)
        out.append(image.reshape(size_px, over, size_px, over).mean(axis=(1, 3)))
    return out


def pattern_table(subset_px: int, order: int, *, contrast: float = 0.8, density: float = 0.5,
                  interpolation: str = "biquintic", seed: int = 0, speckle_px=SPECKLE_PX, defocus_px=DEFOCUS_PX,
                  diffraction_px=DIFFRACTION_PX) -> PatternTable:
    """Tabulate the instrument's match covariance on the paint (module notes); ~30 s per table on 2 cores."""
    unit = NoiseModel(sigma_grey=1.0, read_noise_grey=1.0, electrons_per_grey=None, source="design: unit noise")
    half = subset_px // 2
    shape = (len(speckle_px), len(defocus_px), len(diffraction_px))
    cov, kappa, mig = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    blurs = [(c, g) for c in defocus_px for g in diffraction_px]
    for i, s in enumerate(speckle_px):
        # room for several subsets and several coarse speckles
        size = int(max(4 * subset_px, 12 * s, 96))
        images = paint_images(s, blurs, size, contrast=contrast, density=density, seed=seed + i)
        centres = np.arange(half + 4, size - half - 4, max(subset_px // 2, 4))
        xs, ys = (v.ravel() for v in np.meshgrid(centres, centres))
        for (j, k), image in zip(np.ndindex(shape[1:]), images):
            grey = E0_GREY * image
            sub = reference_subsets(grey, xs, ys, subset_px, order, unit, interpolation)
            c = sub.cov_uv_reference[sub.ok]
            cov[i, j, k] = float(np.mean(0.5 * (c[:, 0, 0] + c[:, 1, 1]))) if len(c) else np.inf
            kappa[i, j, k] = float(np.mean(0.5 * (sub.gains.kappa_u + sub.gains.kappa_v)))
            mig[i, j, k] = mean_intensity_gradient(grey) / E0_GREY
    return PatternTable(np.asarray(speckle_px, float), np.asarray(defocus_px, float), np.asarray(diffraction_px, float),
                        cov, kappa, mig, int(subset_px), int(order), float(contrast), float(density))
