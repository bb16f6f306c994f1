"""Exact "Star" image pairs of the DIC Challenge 2.0 (the truth side, no rendering).

The Star displacement
---------------------
The DIC Challenge 2.0 (Reu et al. 2022, "DIC Challenge 2.0: Developing Images and Guidelines for Evaluating
Accuracy and Resolution of 2D Analyses", Exp. Mech. 62:639, doi 10.1007/s11340-021-00806-6) measures the
spatial resolution of a 2-D DIC code on the "Star" images: 4000 x 501 px (columns x rows), a vertical
displacement only, a sinusoid *along y* of amplitude 0.5 px whose period grows linearly *along x*, from
10 px at the left edge to 300 px at the right edge, with its crest on the middle row::

    U(X, Y) = 0,    V(X, Y) = A cos(2 pi (Y - y0) / p(X)),    p(X) = p_min + (p_max - p_min) X / W

with ``A = 0.5`` px, ``y0 = 250`` (the middle of the 501 rows), ``p_min = 10`` px, ``p_max = 300`` px and
``W = 4000`` px, so ``dp/dX = 0.0725``. Lines of constant phase are straight rays through the virtual apex
``(X, Y) = (-p_min W / (p_max - p_min), y0)``, left of the image: the fan of stripes that gives the
pattern its name. On the middle row every column sits on a crest (``V = A``), and the Challenge reads the
attenuation of the measured crest, column by column, as a function of the period ``p(X)``.

Sources and how the definition was pinned down:

* pyvale's DIC Challenge example (``pyvale/examples/dic/ex04_dic_challenge.py``, and its page
  computer-aided-validation-laboratory.github.io/pyvale/examples/dic/ex5_dic_challenge.html): "+-0.5 pixel
  sinusoidal vertical displacement amplitude 'star' pattern with varying spatial frequency", correlated
  along the middle row (y = 250) against the peak value 0.5 px, lower spatial frequency at the right;
* a public Python snippet in the code index, ``star_displacement(n, m, amplitude=0.5)``, with
  ``amplitude * cos(2 pi xi / wavelength)``, ``xi`` the offset from the middle row and the wavelength linear
  from 10 px to ``150 / 2000 * m`` (300 px for ``m = 4000``) across the columns;
* checked here on the Challenge's own pair as shipped with pyvale (``DIC_Challenge_Star_Noise_Ref.tiff`` /
  ``_Def.tiff``, 501 x 4000 px, 8 bit): fitting ``a cos(2 pi (y - 250)/p) + b sin(...)`` to our engine's v
  (subset 21, second order) along single columns gave ``p`` = 39.0, 82.6, 155.4, 227.3, 285.3 px at x = 400,
  1000, 2000, 3000, 3800 px, against 39.0, 82.5, 155.0, 227.5, 285.5 px from the formula, with ``a`` between
  0.48 and 0.50 px, ``|b| < 0.005`` px and no measurable u.

What the Challenge does not say and is chosen here: the truth is in the *material-point* convention, ``V``
is the displacement of the reference point ``(X, Y)`` (see :mod:`scenes.image_pairs.gaussian_speckle`), and ``X`` is the
0-based column of the reference image. A reduced image (fewer rows and columns, e.g. 201 x 1000 px) keeps
the Challenge's period range, with ``W`` the reduced width and ``y0`` its middle row, so its stripes fan out
faster (``dp/dX = 0.29`` for 1000 columns).

Images
------
The speckle is an analytic :class:`scenes.image_pairs.gaussian_speckle.GaussianSpeckle`, sampled exactly at the pixel
centres (reference) and at the material points of the deformed pixel centres, solved by Newton's method
from the exact gradient (:meth:`GaussianSpeckle.render_deformed`). Sensor noise (read noise and 8-bit
quantisation by default) comes from :func:`scenes.sensor.noise.apply_sensor_noise` with seeds derived from ``seed``:
noise draw ``k`` uses ``SeedSequence([seed, k])`` (k = 0 reference, 1 deformed, 2 the static repeat), so a
Star pair and its static pair share the same reference image exactly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.sensor.noise import apply_sensor_noise
from scenes.surfaces.speckle import require_finite, require_positive_finite
from scenes.image_pairs.gaussian_speckle import (GaussianSpeckle, check_image_shape, extent_for_shape, gaussian_speckle,
                                                 radius_for_speckle_size)
from scenes.image_pairs.analytic_fields import broadcast_xy

#: Size of the Challenge's Star images, (rows, cols) px.
CHALLENGE_SHAPE = (501, 4000)

#: Period range of the Challenge's Star sinusoid, (left edge, right edge) px.
CHALLENGE_PERIODS_PX = (10.0, 300.0)

#: Amplitude of the Challenge's Star displacement, px.
CHALLENGE_AMPLITUDE_PX = 0.5

#: Default autocorrelation speckle size, px (the Challenge pair reads about 4.6 px, noise included).
DEFAULT_SPECKLE_PX = 4.0

#: Default read noise, grey levels (std), before 8-bit quantisation.
DEFAULT_NOISE_GREY = 2.0

#: Margin of the speckle pattern around the image, px (covers displacements up to 6 px).
PATTERN_MARGIN_PX = 8.0

#: Noise draws: which ``k`` of ``SeedSequence([seed, k])`` each image uses.
_NOISE_DRAW = {"reference": 0, "deformed": 1, "static": 2}


@dataclass(frozen=True)
class StarDisplacement:
    """The Star displacement field: ``U = 0``, ``V = A cos(2 pi (Y - y0) / p(X))``, ``p`` linear in ``X``.

    ``p(X) = period_min_px + (period_max_px - period_min_px) X / width_px``; see the module notes. All
    coordinates are reference (material) positions in px, ``X`` the column, ``Y`` the row.

    Attributes
    ----------
    amplitude_px : float
        ``A``, px (finite, > 0).
    period_min_px, period_max_px : float
        Period at ``X = 0`` and at ``X = width_px``, px; ``period_min_px > 2 pi A`` keeps the mapping
        one-to-one (``1 + dV/dY >= 1 - 2 pi A / p > 0``).
    width_px : float
        Span over which the period goes from ``period_min_px`` to ``period_max_px``, px (the image width).
    centre_y_px : float
        ``y0``: the row of the crest line, px (the middle row of the image).
    """

    amplitude_px: float = CHALLENGE_AMPLITUDE_PX
    period_min_px: float = CHALLENGE_PERIODS_PX[0]
    period_max_px: float = CHALLENGE_PERIODS_PX[1]
    width_px: float = float(CHALLENGE_SHAPE[1])
    centre_y_px: float = (CHALLENGE_SHAPE[0] - 1) / 2.0

    def __post_init__(self):
        for name in ("amplitude_px", "period_min_px", "period_max_px", "width_px"):
            object.__setattr__(self, name, require_positive_finite(getattr(self, name), name))
        object.__setattr__(self, "centre_y_px", require_finite(self.centre_y_px, "centre_y_px"))
        if self.period_max_px < self.period_min_px:
            raise ValueError(f"period_max_px ({self.period_max_px}) must be >= period_min_px ({self.period_min_px})")
        if self.period_min_px <= 2.0 * np.pi * self.amplitude_px:
            raise ValueError(
                f"period_min_px={self.period_min_px} must exceed 2 pi amplitude_px = "
                f"{2.0 * np.pi * self.amplitude_px:.3f} px, else the displacement folds the image over")

    @property
    def period_slope(self) -> float:
        """``dp/dX``, px of period per px of X (dimensionless)."""
        return (self.period_max_px - self.period_min_px) / self.width_px

    def period_px(self, X) -> np.ndarray:
        """The local period ``p(X)``, px, shape of ``X``; refused where it would not be positive."""
        p = self.period_min_px + self.period_slope * np.asarray(X, dtype=np.float64)
        if not np.all(p > 0):
            raise ValueError(f"the Star period is not positive at X < {-self.period_min_px / self.period_slope:.1f} "
                             "px (left of the stripes' apex)")
        return p

    def phase(self, X, Y) -> np.ndarray:
        """``phi = 2 pi (Y - y0) / p(X)``, rad, broadcast shape of ``X`` and ``Y``."""
        X, Y = broadcast_xy(X, Y)
        return 2.0 * np.pi * (Y - self.centre_y_px) / self.period_px(X)

    def __call__(self, X, Y):
        X, Y = broadcast_xy(X, Y)
        return np.zeros_like(X), self.amplitude_px * np.cos(self.phase(X, Y))

    def gradient(self, X, Y):
        """``(dU/dX, dU/dY, dV/dX, dV/dY)``, each of the broadcast shape of ``X`` and ``Y``.

        ``dV/dY = -A sin(phi) 2 pi / p`` and ``dV/dX = A sin(phi) 2 pi (Y - y0) p' / p^2`` (``p' = dp/dX``).
        """
        X, Y = broadcast_xy(X, Y)
        p = self.period_px(X)
        s = self.amplitude_px * np.sin(2.0 * np.pi * (Y - self.centre_y_px) / p)
        zero = np.zeros_like(X)
        return (zero, zero.copy(), s * 2.0 * np.pi * (Y - self.centre_y_px) * self.period_slope / p ** 2,
                -s * 2.0 * np.pi / p)

    def stripe_slope(self, X, Y) -> np.ndarray:
        """``|dphi/dX| / |dphi/dY| = |Y - y0| p' / p``: tangent of the stripes' tilt from horizontal.

        Zero on the crest line; a subset there sees a pure sinusoid along y. Away from it the stripes tilt
        and a square subset also averages along x.
        """
        X, Y = broadcast_xy(X, Y)
        return np.abs(Y - self.centre_y_px) * self.period_slope / self.period_px(X)


@dataclass(frozen=True)
class StarImages:
    """A rendered Star case: the moving pair, a static repeat of the reference, and the truth.

    Attributes
    ----------
    reference : ndarray of float32, shape (rows, cols)
        Noisy reference image (noise draw 0), grey levels.
    deformed : ndarray of float32, shape (rows, cols)
        Noisy deformed image (noise draw 1): the reference pattern moved by :attr:`truth`.
    static : ndarray of float32, shape (rows, cols) or None
        The undeformed pattern again with a new noise draw (2): with :attr:`reference` the static pair whose
        measured displacement is pure noise (the noise floor).
    truth : StarDisplacement
        Exact displacement at any reference point.
    """

    reference: np.ndarray
    deformed: np.ndarray | None
    static: np.ndarray | None
    truth: StarDisplacement


def star_displacement_for_shape(shape: tuple[int, int], amplitude_px: float = CHALLENGE_AMPLITUDE_PX,
                                periods_px=CHALLENGE_PERIODS_PX) -> StarDisplacement:
    """The Star field laid over an image of ``shape``: period range over its width, crest on its middle row.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, cols)`` of the image.
    amplitude_px : float
        ``A``, px.
    periods_px : sequence of 2 floats
        ``(p_min, p_max)``: period at the left edge (``X = 0``) and at ``X = cols``, px.

    Returns
    -------
    StarDisplacement
        With ``width_px = cols`` and ``centre_y_px = (rows - 1) / 2``; for :data:`CHALLENGE_SHAPE` it is the
        Challenge's field.
    """
    rows, cols = check_image_shape(shape, minimum=8)
    p_min, p_max = _check_periods(periods_px)
    return StarDisplacement(amplitude_px, p_min, p_max, float(cols), (rows - 1) / 2.0)


def star_speckle(shape: tuple[int, int], speckle_size_px: float = DEFAULT_SPECKLE_PX, seed: int = 0, *,
                 density: float = 0.5, mean_grey: float = 128.0, std_grey: float = 30.0) -> GaussianSpeckle:
    """The analytic speckle pattern of a Star case (what :func:`star_images` samples).

    Parameters
    ----------
    shape : tuple of int
        ``(rows, cols)`` of the images.
    speckle_size_px, seed, density, mean_grey, std_grey
        As in :func:`star_images`.

    Returns
    -------
    GaussianSpeckle
        Non-periodic, uniform statistics over the image plus :data:`PATTERN_MARGIN_PX` on every side (where
        the material points of the deformed pixels lie); it does not depend on the displacement, so a Star
        pair and a static pair of the same seed share it.
    """
    rows, cols = check_image_shape(shape, minimum=8)
    return gaussian_speckle(extent_for_shape((rows, cols), margin_px=PATTERN_MARGIN_PX),
                            radius_for_speckle_size(speckle_size_px), density, _check_seed(seed),
                            mean_grey=mean_grey, std_grey=std_grey)


def star_images(shape: tuple[int, int] = CHALLENGE_SHAPE, speckle_size_px: float = DEFAULT_SPECKLE_PX,
                amplitude_px: float = CHALLENGE_AMPLITUDE_PX, periods_px=CHALLENGE_PERIODS_PX,
                noise_grey: float = DEFAULT_NOISE_GREY, seed: int = 0, *, bit_depth: int | None = 8,
                density: float = 0.5, mean_grey: float = 128.0, std_grey: float = 30.0,
                deformed: bool = True, static: bool = True) -> StarImages:
    """Render a Star case exactly: reference, deformed and a static repeat, from one speckle pattern.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, cols)``, each >= 8; :data:`CHALLENGE_SHAPE` (501 x 4000 px) is the Challenge's size, e.g.
        ``(201, 1000)`` a reduced one.
    speckle_size_px : float
        Autocorrelation speckle size of the pattern, px (:func:`scenes.image_pairs.gaussian_speckle.radius_for_speckle_size`).
    amplitude_px : float
        Amplitude ``A`` of the sinusoid, px.
    periods_px : sequence of 2 floats
        ``(p_min, p_max)`` over the width, px (:func:`star_displacement_for_shape`).
    noise_grey : float
        Gaussian read noise, grey-level std (>= 0), in every image independently.
    seed : int
        Seed of the pattern (``gaussian_speckle``) and of the noise draws (``SeedSequence([seed, k])``).
    bit_depth : {8, 16} or None
        Quantisation of :func:`scenes.sensor.noise.apply_sensor_noise`; None keeps float values.
    density, mean_grey, std_grey : float
        As in :func:`scenes.image_pairs.gaussian_speckle.gaussian_speckle`.
    deformed, static : bool
        Render the deformed image / the static repeat (False leaves them None and saves the time).

    Returns
    -------
    StarImages
    """
    rows, cols = check_image_shape(shape, minimum=8)
    truth = star_displacement_for_shape((rows, cols), amplitude_px, periods_px)
    noise_grey = require_finite(noise_grey, "noise_grey")
    if noise_grey < 0:
        raise ValueError(f"noise_grey must be >= 0, got {noise_grey}")
    if truth.amplitude_px > PATTERN_MARGIN_PX - 2.0:
        raise ValueError(f"amplitude_px={truth.amplitude_px} is above {PATTERN_MARGIN_PX - 2.0} px, the largest "
                         "displacement the pattern's margin covers")
    pattern = star_speckle((rows, cols), speckle_size_px, seed, density=density, mean_grey=mean_grey,
                           std_grey=std_grey)
    seed = _check_seed(seed)
    clean_reference = pattern.render_reference((rows, cols))

    def noisy(image: np.ndarray, which: str) -> np.ndarray:
        return apply_sensor_noise(image, read_noise_grey=noise_grey, bit_depth=bit_depth,
                                  seed=_noise_seed(seed, _NOISE_DRAW[which]))

    moved = noisy(pattern.render_deformed((rows, cols), truth), "deformed") if deformed else None
    repeat = noisy(clean_reference, "static") if static else None
    return StarImages(noisy(clean_reference, "reference"), moved, repeat, truth)


def star_pair(shape: tuple[int, int] = CHALLENGE_SHAPE, speckle_size_px: float = DEFAULT_SPECKLE_PX,
              amplitude_px: float = CHALLENGE_AMPLITUDE_PX, periods_px=CHALLENGE_PERIODS_PX,
              noise_grey: float = DEFAULT_NOISE_GREY, seed: int = 0,
              **options) -> tuple[np.ndarray, np.ndarray, StarDisplacement]:
    """The Star pair: ``(reference, deformed, truth)``; arguments as :func:`star_images`.

    Returns
    -------
    reference, deformed : ndarray of float32, shape (rows, cols)
        Grey levels, independent noise draws.
    truth : StarDisplacement
        ``truth(X, Y) -> (U, V)`` px at reference points; the deformed image is ``g(X + u(X)) = f(X)``.
    """
    images = star_images(shape, speckle_size_px, amplitude_px, periods_px, noise_grey, seed, static=False,
                         **options)
    return images.reference, images.deformed, images.truth


def star_static_pair(shape: tuple[int, int] = CHALLENGE_SHAPE, speckle_size_px: float = DEFAULT_SPECKLE_PX,
                     noise_grey: float = DEFAULT_NOISE_GREY, seed: int = 0,
                     **options) -> tuple[np.ndarray, np.ndarray]:
    """The static pair of a Star case: the same pattern twice, two noise draws (zero displacement).

    The first image is exactly the ``reference`` of :func:`star_pair` with the same shape, speckle size, noise,
    seed and pattern options (the pattern does not depend on the displacement); arguments as
    :func:`star_images`.

    Returns
    -------
    reference, repeat : ndarray of float32, shape (rows, cols)
    """
    images = star_images(shape, speckle_size_px, noise_grey=noise_grey, seed=seed, deformed=False, **options)
    return images.reference, images.static


# ------------------------------------------------------------------------------------------------------------
def _noise_seed(seed: int, draw: int) -> int:
    """Seed of noise draw ``draw`` of the case ``seed``: independent streams from one integer."""
    return int(np.random.SeedSequence([seed, draw]).generate_state(1)[0])


def _check_seed(seed) -> int:
    try:
        exact = not isinstance(seed, bool) and int(seed) == seed and seed >= 0
    except (TypeError, ValueError):
        exact = False
    if not exact:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    return int(seed)


def _check_periods(periods_px) -> tuple[float, float]:
    try:
        p_min, p_max = (float(p) for p in periods_px)
    except (TypeError, ValueError):
        raise ValueError(f"periods_px must be two numbers (p_min, p_max) px, got {periods_px!r}") from None
    if not (np.isfinite(p_min) and np.isfinite(p_max) and 0 < p_min <= p_max):
        raise ValueError(f"periods_px must be finite with 0 < p_min <= p_max, got {periods_px!r}")
    return p_min, p_max
