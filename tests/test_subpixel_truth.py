"""The truth below a pixel (issue 38): every render path draws a sub-pixel motion of the paint where it is.

The reference is independent of the renderers' texture: 16 x 16 rays per pixel meet the plate and evaluate the
paint's band-limited interpolant (16 texels per pixel); :func:`scenes.surfaces.speckle.fourier_upsample` itself is checked
against a direct sum of the pattern's Fourier series.
"""
from __future__ import annotations

import numpy as np
import pytest

from scenes.surfaces.speckle import fourier_upsample
from workbench.experiments.subpixel import PlateScene, phase_errors

#: The issue's goal: the render's own sub-pixel error at every phase, px RMS.
RENDER_GOAL_PX = 0.001
#: Phases checked: at rest, half a pixel along x, half along both axes, and an odd fraction.
PHASES = [(0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.375, 0.875)]


def _fourier_series(samples: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The real trigonometric polynomial through ``samples`` (Nyquist terms left out) at points (y, x), summed
    term by term."""
    rows, cols = samples.shape
    F = np.fft.fft2(samples) / samples.size
    fr = np.fft.fftfreq(rows) * rows
    fc = np.fft.fftfreq(cols) * cols
    keep_r = np.abs(fr) < rows / 2
    keep_c = np.abs(fc) < cols / 2
    total = np.zeros(y.shape, complex)
    for i in np.flatnonzero(keep_r):
        for j in np.flatnonzero(keep_c):
            total += F[i, j] * np.exp(2j * np.pi * (fr[i] * y / rows + fc[j] * x / cols))
    return total.real


@pytest.mark.parametrize("shape, factor", [((9, 12), 3), ((10, 7), 4), ((8, 8), 1)])
def test_fourier_upsample_is_the_trigonometric_interpolant_at_the_fine_texel_centres(shape, factor):
    """Every fine texel equals the pattern's Fourier series at its centre, ``(k + 0.5) / factor - 0.5`` in coarse
    texels (1e-5 of the range; float32), odd and even sizes; factor 1 returns the samples."""
    samples = np.random.default_rng(4).random(shape)
    fine = fourier_upsample(samples, factor)
    assert fine.shape == (shape[0] * factor, shape[1] * factor) and fine.dtype == np.float32
    if factor == 1:
        assert np.array_equal(fine, samples.astype(np.float32))
        return
    k_r, k_c = np.meshgrid(np.arange(fine.shape[0]), np.arange(fine.shape[1]), indexing="ij")
    expected = _fourier_series(samples, (k_r + 0.5) / factor - 0.5, (k_c + 0.5) / factor - 0.5)
    assert np.abs(fine - expected).max() < 1e-5


def test_fourier_upsample_refuses_a_fractional_factor():
    with pytest.raises(ValueError, match="factor must be an integer >= 1, got 2.5"):
        fourier_upsample(np.zeros((4, 4)), 2.5)


@pytest.mark.parametrize("path", ["quadrature", "occlusion", "thin lens in focus", "mitsuba"])
def test_every_render_path_draws_the_plate_within_0_001_px_of_the_paint_at_every_phase(path):
    """The render's own error (DIC from the converged reference to the render of the same position) is at most
    0.001 px RMS at rest and at sub-pixel phases, for the default paint (speckle 5 px); Mitsuba at 0.05 grey of
    Monte-Carlo noise."""
    rows = phase_errors(PlateScene(), path, PHASES)
    for r in rows:
        assert r["points"] >= 100, r
        assert r["render_rms_px"] <= RENDER_GOAL_PX, (path, r)


def test_the_paint_looked_up_at_its_pattern_texels_fails_the_check():
    """The texture as it was before issue 38 (the pattern itself, 5 texels per speckle, about one per pixel) is
    caught: its render error exceeds 0.005 px and a half-pixel motion is measured 0.005 px wrong."""
    rows = phase_errors(PlateScene(lookup_factor=1), "quadrature", [(0.0, 0.0), (0.5, 0.5)])
    assert min(r["render_rms_px"] for r in rows) > 5 * RENDER_GOAL_PX
    assert rows[1]["motion_rms_px"] > 5 * RENDER_GOAL_PX


def test_one_sample_per_pixel_fails_the_check():
    """A renderer that point-samples each pixel at its centre (a 1 x 1 rule locked to the pixel grid) is caught:
    its render error exceeds 0.002 px."""
    rows = phase_errors(PlateScene(), "quadrature", [(0.5, 0.5)], quadrature_order=1)
    assert rows[0]["render_rms_px"] > 2 * RENDER_GOAL_PX


def test_a_half_pixel_motion_is_measured_as_well_as_the_instrument_alone_measures_the_exact_images():
    """The instrument on two renders (at rest, moved by (0.5, 0.5) px) errs within 0.0005 px of what it errs on
    the two converged references (the exact images): the render adds nothing measurable to a sub-pixel motion."""
    r = phase_errors(PlateScene(), "quadrature", [(0.5, 0.5)])[0]
    assert r["motion_rms_px"] <= r["instrument_alone_rms_px"] + 0.0005, r


def _periodic_photo() -> np.ndarray:
    """A periodic 5 px speckle 'photograph' (grey 20-220), whose exact sub-pixel motion is its Fourier shift."""
    from scenes.surfaces.speckle import speckle_pattern

    return 20.0 + 200.0 * speckle_pattern((128, 128), 5.0, contrast=0.8, seed=3).astype(float)


def test_the_twins_photograph_moves_within_0_001_px_of_its_band_limited_shift():
    """The twin's texture (a photograph read as a continuous function) moved by sub-pixel phases is its exact
    band-limited shift within 0.001 px RMS (DIC from the Fourier-shifted photo to the twin's image)."""
    from workbench.experiments.subpixel import photo_phase_errors

    for r in photo_phase_errors(_periodic_photo(), [(0.25, 0.0), (0.5, 0.5), (0.75, 0.25)]):
        assert r["points"] >= 100 and r["render_rms_px"] <= RENDER_GOAL_PX, r


def test_a_cubic_spline_through_the_photographs_pixels_fails_the_check(monkeypatch):
    """The twin's texture as it was (a cubic B-spline through the pixels themselves, no finer samples) is caught:
    at a (0.75, 0.25) px phase it moves the pattern by more than 0.001 px."""
    import scenes.surfaces.image_texture
    from workbench.experiments.subpixel import photo_phase_errors

    monkeypatch.setattr(scenes.surfaces.image_texture, "UPSAMPLE", 1)
    r = photo_phase_errors(_periodic_photo(), [(0.75, 0.25)])[0]
    assert r["render_rms_px"] > RENDER_GOAL_PX, r


def test_a_sharp_paint_aliases_without_optics_and_the_lens_diffraction_low_passes_it():
    """Speckle aliasing is physical, and the optics decide it (noise-free motion error over sub-pixel phases):
    sharp-edged 5 px speckles (0.1 px edges) through ideal optics are measured more than 0.01 px wrong; through
    the diffraction of f/8 (3.45 um pixels) under a quarter of that; soft speckles at f/8 under 0.001 px."""
    from workbench.experiments.subpixel import aliasing_study

    rows = {(r["edge"], r["f_number"]): r["worst_rms_px"]
            for r in aliasing_study(speckles_px=(5.0,), f_numbers=(None, 8.0), phases_px=[(0.25, 0.0), (0.5, 0.5)])}
    assert rows[("sharp", None)] > 0.01
    assert rows[("sharp", 8.0)] < 0.25 * rows[("sharp", None)]
    assert rows[("soft", 8.0)] < RENDER_GOAL_PX
