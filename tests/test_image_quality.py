"""Tests for measurement.image_quality: the mean intensity gradient (MIG)."""
import numpy as np
import pytest
from scipy import ndimage

from measurement.image_quality import gradient_magnitude, mean_intensity_gradient
from scenes.surfaces.speckle import speckle_pattern


def test_linear_ramp_gives_its_slope():
    cols = np.arange(64, dtype=np.float64)
    ramp = np.tile(2.0 * cols, (48, 1))           # 2 grey per pixel along columns
    assert mean_intensity_gradient(ramp) == pytest.approx(2.0, abs=1e-12)
    assert mean_intensity_gradient(ramp.T) == pytest.approx(2.0, abs=1e-12)
    magnitude = gradient_magnitude(ramp)
    np.testing.assert_allclose(magnitude[1:-1, 1:-1], 2.0)
    # the replicated border halves the one-sided difference there, which is why MIG skips the border
    np.testing.assert_allclose(magnitude[5, [0, -1]], 1.0)


def test_diagonal_ramp_gives_gradient_norm():
    rows, cols = np.mgrid[0:40, 0:50].astype(np.float64)
    image = 3.0 * rows + 4.0 * cols
    assert mean_intensity_gradient(image) == pytest.approx(5.0, abs=1e-12)


def test_flat_image_has_zero_mig():
    assert mean_intensity_gradient(np.full((16, 16), 100, dtype=np.uint8)) == 0.0


def test_blurring_lowers_mig():
    sharp = 255.0 * speckle_pattern((256, 256), 6.0, seed=1).astype(np.float64)
    blurred = ndimage.gaussian_filter(sharp, 2.0, mode="wrap")
    mig_sharp = mean_intensity_gradient(sharp)
    mig_blurred = mean_intensity_gradient(blurred)
    assert mig_sharp > 10.0                         # a black/white speckle pattern is strongly textured
    assert mig_blurred < 0.7 * mig_sharp


def test_mig_scales_with_contrast():
    pattern = speckle_pattern((128, 128), 6.0, seed=2).astype(np.float64)
    assert mean_intensity_gradient(3.0 * pattern) == pytest.approx(3.0 * mean_intensity_gradient(pattern))


def test_mask_selects_pixels():
    cols = np.arange(100, dtype=np.float64)
    # slope 1 grey/px on the left half, slope 3 on the right half
    profile = np.where(cols < 50, cols, 50.0 + 3.0 * (cols - 50))
    image = np.tile(profile, (30, 1))
    left = np.zeros(image.shape, dtype=bool)
    left[:, :45] = True
    right = np.zeros(image.shape, dtype=bool)
    right[:, 55:] = True
    assert mean_intensity_gradient(image, mask=left) == pytest.approx(1.0, abs=1e-12)
    assert mean_intensity_gradient(image, mask=right) == pytest.approx(3.0, abs=1e-12)
    whole = mean_intensity_gradient(image)
    assert 1.0 < whole < 3.0


def test_mask_errors():
    image = np.random.default_rng(0).random((20, 20))
    with pytest.raises(ValueError, match="boolean"):
        mean_intensity_gradient(image, mask=np.ones((20, 20)))
    with pytest.raises(ValueError, match="shape"):
        mean_intensity_gradient(image, mask=np.ones((20, 21), dtype=bool))
    only_border = np.zeros((20, 20), dtype=bool)
    only_border[0, :] = True
    with pytest.raises(ValueError, match="no interior pixels"):
        mean_intensity_gradient(image, mask=only_border)


def test_bad_images_raise():
    with pytest.raises(ValueError, match="2-D"):
        mean_intensity_gradient(np.zeros((8, 8, 3)))
    with pytest.raises(ValueError, match="3 x 3"):
        mean_intensity_gradient(np.zeros((2, 8)))
    image = np.zeros((8, 8))
    image[2, 2] = np.nan
    with pytest.raises(ValueError, match="1 non-finite"):
        mean_intensity_gradient(image)
