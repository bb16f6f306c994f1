"""The instrument's match uncertainty on a speckle image of a given size and blur, tabulated for the designer.

A candidate rig is judged before any image exists, so the designer cannot run the instrument on the rig's own
images; it runs it on small synthetic images of the same paint instead. For each speckle diameter ``s`` (px in the
image) and blur ``b`` (Gaussian sigma in px: defocus and diffraction) an image of the paint is made as the renderer
makes it (:func:`scenes.speckle.speckle_pattern` with the paint's density, contrast and soft edge, sampled four
times finer, blurred, box-averaged over each pixel) at a fixed exposure ``E0`` and the instrument's own estimator,
:func:`measurement.uncertainty.match.reference_subsets` (the IC-GN Hessian and the image noise), gives the
covariance of (u, v) per unit noise variance, averaged over the image's subsets. One table per subset size, shape
function order and paint; the designer reads it at each ROI point of each candidate (bilinear in log s and b) and
scales it by the candidate's noise and exposure: ``Cov = sigma_n^2 (E0 / E)^2 T(s, b)`` (the Hessian grows with the
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
from scenes.speckle import speckle_pattern

#: Exposure of the table's images: grey of paint value 1, so high that unit noise leaves the Hessian noise-free (the
#: noise enters only through the scaling, module notes).
E0_GREY = 1.0e6
#: Oversampling of the paint before the pixels average it.
OVERSAMPLE = 4
#: Speckle diameters (px) and blur sigmas (px) of the table.
SPECKLE_PX = tuple(float(v) for v in np.geomspace(1.5, 32.0, 12))
BLUR_PX = (0.0, 0.3, 0.6, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0)


@dataclass(frozen=True)
class PatternTable:
    """The instrument's (u, v) covariance on the paint, per unit noise variance at exposure :data:`E0_GREY`.

    Attributes
    ----------
    speckle_px, blur_px : ndarray (S,), (B,)
    cov_px2 : ndarray (S, B)
        Mean over subsets of ``(Cov_uu + Cov_vv) / 2`` (the texture is isotropic), px^2 per grey^2.
    kappa : ndarray (S, B)
        Mean over sub-pixel phases of the interpolant's gain on the noise a target image adds (<= 1).
    mig_per_exposure : ndarray (S, B)
        Mean intensity gradient of the image per unit exposure (grey/px per grey).
    subset_px, order : int
    contrast, density : float
    """

    speckle_px: np.ndarray
    blur_px: np.ndarray
    cov_px2: np.ndarray = field(repr=False)
    kappa: np.ndarray = field(repr=False)
    mig_per_exposure: np.ndarray = field(repr=False)
    subset_px: int = 33
    order: int = 1
    contrast: float = 0.8
    density: float = 0.5

    def _interp(self, table: np.ndarray, speckle_px, blur_px, log: bool) -> np.ndarray:
        s = np.clip(np.asarray(speckle_px, float), self.speckle_px[0], self.speckle_px[-1])
        b = np.clip(np.asarray(blur_px, float), self.blur_px[0], self.blur_px[-1])
        ls, lt = np.log(self.speckle_px), np.log(s)
        i = np.clip(np.searchsorted(ls, lt) - 1, 0, ls.size - 2)
        a = (lt - ls[i]) / (ls[i + 1] - ls[i])
        j = np.clip(np.searchsorted(self.blur_px, b) - 1, 0, self.blur_px.size - 2)
        c = (b - self.blur_px[j]) / (self.blur_px[j + 1] - self.blur_px[j])
        t = np.log(table) if log else table
        v = ((1 - a) * (1 - c) * t[i, j] + a * (1 - c) * t[i + 1, j] + (1 - a) * c * t[i, j + 1]
             + a * c * t[i + 1, j + 1])
        return np.exp(v) if log else v

    def covariance(self, speckle_px, blur_px) -> np.ndarray:
        """Tabulated (u, v) variance per unit noise variance at E0, px^2/grey^2 (log-bilinear)."""
        return self._interp(self.cov_px2, speckle_px, blur_px, log=True)

    def noise_gain(self, speckle_px, blur_px) -> np.ndarray:
        return self._interp(self.kappa, speckle_px, blur_px, log=False)

    def mig(self, speckle_px, blur_px) -> np.ndarray:
        return self._interp(self.mig_per_exposure, speckle_px, blur_px, log=True)

    def out_of_range(self, speckle_px, blur_px) -> np.ndarray:
        """Where a lookup was clipped to the table's edge (the prediction is extrapolated there)."""
        s = np.asarray(speckle_px, float)
        b = np.asarray(blur_px, float)
        return (s < self.speckle_px[0]) | (s > self.speckle_px[-1]) | (b > self.blur_px[-1])


#: Texels per speckle diameter of a paint's samples (:attr:`scenes.paint.Paint.texel`: speckle / 5).
PAINT_TEXELS_PER_SPECKLE = 5.0


def paint_images(speckle_px: float, blurs_px, size_px: int, *, contrast: float = 0.8, density: float = 0.5,
                 seed: int = 0) -> list[np.ndarray]:
    """Images (size_px square) of the paint with speckle ``speckle_px`` at each blur sigma, as the renderer makes them.

    The paint is what :mod:`scenes.paint` renders: the speckle's samples at ``speckle / 5`` texels
    (:func:`scenes.speckle.speckle_pattern`, the paint's soft edge) and their band-limited (Fourier) interpolant;
    here that interpolant is evaluated on a grid :data:`OVERSAMPLE` (or more) times finer than the pixels, blurred
    by a Gaussian of each sigma and averaged over each pixel. The texel count is rounded so that the periodic
    pattern spans the patch exactly (the speckle is then ``5 size / round(5 size / speckle)`` px, within 1 %).
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
    out = []
    for b in blurs_px:
        transfer = np.exp(-2.0 * np.pi ** 2 * (b * over) ** 2 * (fx ** 2 + fy ** 2))
        image = np.fft.ifft2(fine * transfer).real * (n * n) / (texels * texels)
        out.append(image.reshape(size_px, over, size_px, over).mean(axis=(1, 3)))
    return out


def pattern_table(subset_px: int, order: int, *, contrast: float = 0.8, density: float = 0.5,
                  interpolation: str = "biquintic", seed: int = 0, speckle_px=SPECKLE_PX,
                  blur_px=BLUR_PX) -> PatternTable:
    """Tabulate the instrument's match covariance on the paint (module notes); a few seconds per table."""
    unit = NoiseModel(sigma_grey=1.0, read_noise_grey=1.0, electrons_per_grey=None, source="design: unit noise")
    half = subset_px // 2
    S, B = len(speckle_px), len(blur_px)
    cov = np.zeros((S, B))
    kappa = np.zeros((S, B))
    mig = np.zeros((S, B))
    for i, s in enumerate(speckle_px):
        # room for several subsets and several coarse speckles
        size = int(max(4 * subset_px, 12 * s, 96))
        images = paint_images(s, blur_px, size, contrast=contrast, density=density, seed=seed + i)
        centres = np.arange(half + 4, size - half - 4, max(subset_px // 2, 4))
        xs, ys = (v.ravel() for v in np.meshgrid(centres, centres))
        for j, image in enumerate(images):
            grey = E0_GREY * image
            sub = reference_subsets(grey, xs, ys, subset_px, order, unit, interpolation)
            c = sub.cov_uv_reference[sub.ok]
            cov[i, j] = float(np.mean(0.5 * (c[:, 0, 0] + c[:, 1, 1]))) if len(c) else np.inf
            kappa[i, j] = float(np.mean(0.5 * (sub.gains.kappa_u + sub.gains.kappa_v)))
            mig[i, j] = mean_intensity_gradient(grey) / E0_GREY
    return PatternTable(np.asarray(speckle_px, float), np.asarray(blur_px, float), cov, kappa, mig, int(subset_px),
                        int(order), float(contrast), float(density))
