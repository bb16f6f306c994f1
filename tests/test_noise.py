"""Tests for scenes.sensor.noise: the sensor-noise model."""
import numpy as np
import pytest

from scenes.sensor.noise import SensorNoise, apply_sensor_noise, max_grey, noise_sigma_grey, to_image_dtype

FLAT_SHAPE = (1024, 1024)


@pytest.mark.parametrize("signal, read, gain", [
    (100.3, 2.0, 4.0),     # shot noise dominates
    (40.7, 3.0, 50.0),     # read noise dominates
    (120.2, 0.5, None),    # quantisation is a quarter of the variance
])
def test_flat_image_std_and_mean_match_theory(signal, read, gain):
    clean = np.full(FLAT_SHAPE, signal)
    noisy = apply_sensor_noise(clean, read_noise_grey=read, electrons_per_grey=gain, bit_depth=8, seed=11)
    shot_var = signal / gain if gain else 0.0
    expected_std = np.sqrt(read**2 + shot_var + 1.0 / 12.0)
    residual = noisy.astype(np.float64) - clean
    assert residual.std() == pytest.approx(expected_std, rel=0.05)
    assert abs(residual.mean()) < 0.05
    predicted = noise_sigma_grey(clean, read, gain, 8)
    assert predicted.shape == clean.shape
    np.testing.assert_allclose(predicted, expected_std)


def test_shot_noise_variance_scales_with_signal():
    gain = 2.0
    low = apply_sensor_noise(np.full(FLAT_SHAPE, 20.0), electrons_per_grey=gain, bit_depth=None, seed=1)
    high = apply_sensor_noise(np.full(FLAT_SHAPE, 180.0), electrons_per_grey=gain, bit_depth=None, seed=1)
    assert low.var() == pytest.approx(20.0 / gain, rel=0.05)
    assert high.var() == pytest.approx(180.0 / gain, rel=0.05)


def test_unquantised_output_is_float_and_unclipped():
    clean = np.zeros((256, 256))
    noisy = apply_sensor_noise(clean, read_noise_grey=1.0, bit_depth=None, seed=3)
    assert noisy.dtype == np.float32
    assert noisy.min() < -2.0          # negative excursions survive without quantisation
    assert not np.all(noisy == np.rint(noisy))
    assert noisy.std() == pytest.approx(1.0, rel=0.05)


def test_quantised_output_is_integral_and_clipped():
    clean = np.concatenate([np.full((256, 128), 1.0), np.full((256, 128), 254.0)], axis=1)
    noisy = apply_sensor_noise(clean, read_noise_grey=5.0, bit_depth=8, seed=4)
    assert noisy.dtype == np.float32
    np.testing.assert_array_equal(noisy, np.rint(noisy))
    assert noisy.min() == 0.0 and noisy.max() == 255.0
    # clipping piles up at the rails: both sides are hit by a sizeable fraction of pixels
    assert np.mean(noisy == 0.0) > 0.1 and np.mean(noisy == 255.0) > 0.1


def test_sixteen_bit():
    clean = np.full((512, 512), 40000.5)
    noisy = apply_sensor_noise(clean, read_noise_grey=10.0, electrons_per_grey=0.5, bit_depth=16, seed=5)
    np.testing.assert_array_equal(noisy, np.rint(noisy))
    assert noisy.max() <= 65535
    expected_std = np.sqrt(10.0**2 + 40000.5 / 0.5 + 1.0 / 12.0)
    assert noisy.std() == pytest.approx(expected_std, rel=0.05)
    assert abs(noisy.mean() - 40000.5) < 1.0   # std ~ 283 grey over 262k pixels: s.e. 0.55
    saturated = apply_sensor_noise(np.full((8, 8), 70000.0), bit_depth=16)
    assert np.all(saturated == 65535)


def test_no_noise_only_rounds():
    clean = np.array([[0.4, 0.6, 254.5], [300.0, -3.0, 17.2]])
    out = apply_sensor_noise(clean, bit_depth=8)
    np.testing.assert_array_equal(out, [[0, 1, 254], [255, 0, 17]])


def test_determinism():
    clean = np.full((128, 128), 80.0)
    kwargs = dict(read_noise_grey=2.0, electrons_per_grey=3.0)
    a = apply_sensor_noise(clean, seed=21, **kwargs)
    b = apply_sensor_noise(clean, seed=21, **kwargs)
    c = apply_sensor_noise(clean, seed=22, **kwargs)
    np.testing.assert_array_equal(a, b)
    assert np.mean(a != c) > 0.5


def test_sensor_noise_dataclass_matches_function():
    model = SensorNoise(read_noise_grey=1.5, electrons_per_grey=8.0, bit_depth=16)
    clean = np.linspace(0, 1000, 64 * 64).reshape(64, 64)
    np.testing.assert_array_equal(
        model.apply(clean, seed=9),
        apply_sensor_noise(clean, read_noise_grey=1.5, electrons_per_grey=8.0, bit_depth=16, seed=9))
    np.testing.assert_allclose(model.sigma_grey(clean), noise_sigma_grey(clean, 1.5, 8.0, 16))
    with pytest.raises(ValueError, match="bit_depth"):
        SensorNoise(bit_depth=12)


def test_to_image_dtype():
    image = np.array([[-1.0, 0.4, 127.6], [255.2, 300.0, 65535.7]])
    as8 = to_image_dtype(image, 8)
    as16 = to_image_dtype(image, 16)
    assert as8.dtype == np.uint8 and as16.dtype == np.uint16
    np.testing.assert_array_equal(as8, [[0, 0, 128], [255, 255, 255]])
    np.testing.assert_array_equal(as16, [[0, 0, 128], [255, 300, 65535]])
    assert max_grey(8) == 255 and max_grey(16) == 65535
    with pytest.raises(ValueError, match="bit_depth"):
        to_image_dtype(image, None)


@pytest.mark.parametrize("kwargs, match", [
    (dict(read_noise_grey=-1.0), "read_noise_grey"),
    (dict(read_noise_grey=float("inf")), "read_noise_grey"),
    (dict(electrons_per_grey=0.0), "electrons_per_grey"),
    (dict(electrons_per_grey=-2.0), "electrons_per_grey"),
    (dict(bit_depth=12), "bit_depth"),
    (dict(bit_depth=True), "bit_depth"),
])
def test_bad_parameters_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        apply_sensor_noise(np.full((4, 4), 10.0), **kwargs)


def test_nan_input_reports_count():
    clean = np.full((8, 8), 10.0)
    clean[1, 2] = clean[5, 5] = clean[7, 0] = np.nan
    with pytest.raises(ValueError, match="3 NaN pixels"):
        apply_sensor_noise(clean)


def test_negative_signal_with_shot_noise_raises():
    with pytest.raises(ValueError, match="negative"):
        apply_sensor_noise(np.full((4, 4), -1.0), electrons_per_grey=2.0)
