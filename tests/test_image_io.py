"""measurement.image_io: the one image loader (detection and DIC), its bit-depth report, its refusals and
conversions, and the 8-bit copies for OpenCV's detector and SIFT; the warning on tiny rendered images."""
from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest
import tifffile
from PIL import Image

from measurement.image_io import read_grey, read_grey_info, to_uint8


@pytest.fixture(scope="module")
def speckle12():
    """A smooth 12-bit test picture (0..4095, every low bit used), 48 x 64 px."""
    rng = np.random.default_rng(3)
    from scipy import ndimage
    field = ndimage.gaussian_filter(rng.random((48, 64)), 2.0)
    field = (field - field.min()) / np.ptp(field)
    return np.rint(field * 4095).astype(np.uint16)


# --- paths ------------------------------------------------------------------------------------------------

def test_a_directory_is_named_as_a_directory(tmp_path):
    folder = tmp_path / "images.png"
    folder.mkdir()
    with pytest.raises(ValueError, match=r"images\.png is a directory, not an image file"):
        read_grey(folder)
    with pytest.raises(ValueError, match=r"image file not found: .*missing\.png"):
        read_grey(tmp_path / "missing.png")


def test_empty_and_foreign_files_are_refused_naming_the_file(tmp_path):
    empty = tmp_path / "empty.tif"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match=r"empty\.tif: the file is empty"):
        read_grey(empty)
    text = tmp_path / "notes.png"
    text.write_text("not an image")
    with pytest.raises(ValueError, match=r"cannot read image .*notes\.png"):
        read_grey(text)


# --- bit depth from the data --------------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", ["png", "tif"])
def test_twelve_bit_data_in_a_sixteen_bit_file_is_read_exactly_and_reported(tmp_path, speckle12, suffix):
    low_aligned = tmp_path / f"low.{suffix}"
    high_aligned = tmp_path / f"high.{suffix}"
    assert cv2.imwrite(str(low_aligned), speckle12)
    assert cv2.imwrite(str(high_aligned), speckle12 << 4)
    info = read_grey_info(low_aligned)
    np.testing.assert_array_equal(info.image, speckle12)
    assert info.image.dtype == np.uint16
    assert (info.container_bits, info.bits, info.low_zero_bits) == (16, 12, 0)
    assert info.value_range == (0.0, 4095.0)
    assert info.describe() == "12-bit data in a 16-bit container (values 0..4095)"
    info = read_grey_info(high_aligned)
    np.testing.assert_array_equal(info.image, speckle12 << 4)
    assert (info.container_bits, info.bits, info.low_zero_bits) == (16, 12, 4)
    assert "in the high bits (multiples of 16)" in info.describe()
    full = tmp_path / f"full.{suffix}"
    assert cv2.imwrite(str(full), (speckle12.astype(np.uint32) * 65535 // 4095).astype(np.uint16))
    assert read_grey_info(full).bits == 16
    eight = tmp_path / f"eight.{suffix}"
    assert cv2.imwrite(str(eight), (speckle12 >> 4).astype(np.uint8))
    assert (read_grey_info(eight).container_bits, read_grey_info(eight).bits) == (8, 8)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float_images_stay_float(tmp_path, speckle12, dtype):
    values = (speckle12 / 4095.0).astype(dtype)
    values[0, 0] = np.nan
    path = tmp_path / "float.tif"
    tifffile.imwrite(path, values)
    info = read_grey_info(path)
    assert info.image.dtype == dtype
    np.testing.assert_array_equal(info.image, values)
    assert info.bits is None and info.container_bits is None
    assert info.non_finite == 1
    assert info.value_range[1] == pytest.approx(1.0)
    assert "floating-point data" in info.describe() and "1 non-finite" in info.describe()


def test_half_floats_become_single_and_bilevel_images_0_255(tmp_path, speckle12):
    half = tmp_path / "half.tif"
    tifffile.imwrite(half, (speckle12 / 4095.0).astype(np.float16))
    image = read_grey(half)
    assert image.dtype == np.float32
    np.testing.assert_array_equal(image, (speckle12 / 4095.0).astype(np.float16).astype(np.float32))
    bilevel = tmp_path / "bilevel.tif"
    tifffile.imwrite(bilevel, speckle12 > 2000, photometric="minisblack")
    image = read_grey(bilevel)
    assert image.dtype == np.uint8
    np.testing.assert_array_equal(image, np.where(speckle12 > 2000, 255, 0))
    # tifffile's default for booleans is MINISWHITE: a set bit is black (OpenCV reads it so too)
    tifffile.imwrite(bilevel, speckle12 > 2000)
    np.testing.assert_array_equal(read_grey(bilevel), np.where(speckle12 > 2000, 0, 255))
    np.testing.assert_array_equal(read_grey(bilevel), cv2.imread(str(bilevel), cv2.IMREAD_UNCHANGED))


# --- pages and channels --------------------------------------------------------------------------------------

def test_multi_page_tiffs_and_animations_are_refused(tmp_path, speckle12):
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.stack([speckle12, speckle12 // 2, speckle12 // 3]), photometric="minisblack")
    with pytest.raises(ValueError, match=r"stack\.tif holds 3 pages; expected one grey image"):
        read_grey(stack)
    frames = [Image.fromarray((speckle12 >> 4).astype(np.uint8)), Image.fromarray((speckle12 >> 5).astype(np.uint8))]
    for suffix in ("png", "gif"):
        animation = tmp_path / f"animation.{suffix}"
        frames[0].save(animation, save_all=True, append_images=frames[1:])
        with pytest.raises(ValueError, match=rf"animation\.{suffix} holds 2 pages/frames"):
            read_grey(animation)


@pytest.mark.parametrize("frames", [3, 4])
def test_a_stack_that_tifffile_stored_as_planar_colour_is_refused(tmp_path, speckle12, frames):
    """``tifffile.imwrite(path, np.stack(three_frames))`` writes ONE planar RGB page (four frames: RGBA), which
    was read as a grey mixture of the frames, exit 0; it is refused naming the file and the frame count."""
    stack = np.stack([speckle12 // (k + 1) for k in range(frames)])
    path = tmp_path / "series.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # tifffile's own deprecation note on guessing colour
        tifffile.imwrite(path, stack)
    with tifffile.TiffFile(path) as tif:         # the layout the refusal is about (not a multi-page file)
        assert len(tif.pages) == 1 and tif.pages[0].axes == "SYX"
    with pytest.raises(ValueError, match=rf"series\.tif holds {frames} pages \(planes of 64 x 48 px that tifffile "
                                         rf"stored as one planar RGBA? page"):
        read_grey(path)


def test_two_channel_tiffs_need_a_declared_alpha_channel(tmp_path, speckle12):
    two = np.dstack([speckle12, speckle12[::-1]])
    plain = tmp_path / "two.tif"
    tifffile.imwrite(plain, two, photometric="minisblack", planarconfig="contig")
    with pytest.raises(ValueError, match=r"two\.tif has 2 samples per pixel and the last one is not declared alpha"):
        read_grey(plain)
    alpha = tmp_path / "grey_alpha.tif"
    tifffile.imwrite(alpha, two, photometric="minisblack", extrasamples=["unassalpha"])
    with pytest.warns(UserWarning, match=r"grey_alpha\.tif: its alpha channel is not fully opaque"):
        image = read_grey(alpha)
    np.testing.assert_array_equal(image, speckle12)
    opaque = tmp_path / "opaque.tif"
    tifffile.imwrite(opaque, np.dstack([speckle12, np.full_like(speckle12, 65535)]), photometric="minisblack",
                     extrasamples=["unassalpha"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(read_grey(opaque), speckle12)


def test_more_than_four_channels_are_refused(tmp_path, speckle12):
    path = tmp_path / "five.tif"
    tifffile.imwrite(path, np.dstack([speckle12] * 5), photometric="rgb", extrasamples=["unspecified"] * 2)
    with pytest.raises(ValueError, match=r"five\.tif is RGB with 5 samples per pixel"):
        read_grey(path)


def test_grey_plus_alpha_png_gives_its_grey_channel(tmp_path, speckle12):
    grey = (speckle12 >> 4).astype(np.uint8)
    path = tmp_path / "la.png"
    Image.fromarray(np.dstack([grey, np.full_like(grey, 200)]), "LA").save(path)
    with pytest.warns(UserWarning, match=r"la\.png: its alpha channel is not fully opaque"):
        np.testing.assert_array_equal(read_grey(path), grey)


@pytest.mark.parametrize("layout", ["png", "tif-uint16", "tif-float32", "tif-float64-planar", "tif-int16"])
def test_colour_becomes_grey_with_the_same_weights_in_every_layout(tmp_path, layout):
    rgb = np.zeros((8, 10, 3))
    rgb[..., 0], rgb[:4, :, 1], rgb[:, :5, 2] = 200.0, 100.0, 50.0
    expected = 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]
    path = tmp_path / f"colour.{layout.split('-')[0]}"
    if layout == "png":
        assert cv2.imwrite(str(path), rgb[..., ::-1].astype(np.uint8))      # OpenCV writes BGR
    elif layout == "tif-float64-planar":
        # planar colour as another writer stores it (no tifffile shape metadata: see the stack test below)
        tifffile.imwrite(path, np.moveaxis(rgb, -1, 0), photometric="rgb", planarconfig="separate", metadata=None)
    else:
        tifffile.imwrite(path, rgb.astype(layout.split("-")[1]), photometric="rgb")
    image = read_grey(path)
    assert image.shape == (8, 10)
    # OpenCV rounds integer results (and its fixed-point weights differ by < 0.5 grey); floats are exact.
    tolerance = 0.5 if image.dtype.kind in "ui" else 1e-4
    np.testing.assert_allclose(image, expected, atol=tolerance)


def test_tiffs_with_zero_as_white_are_inverted(tmp_path, speckle12):
    """TIFF's MINISWHITE stores 2^bits - 1 - grey. OpenCV inverts 8-bit such files but not 16-bit ones."""
    path = tmp_path / "miniswhite.tif"
    tifffile.imwrite(path, speckle12, photometric="miniswhite")
    np.testing.assert_array_equal(read_grey(path), 65535 - speckle12)
    eight = (speckle12 >> 4).astype(np.uint8)
    tifffile.imwrite(path, eight, photometric="miniswhite")
    np.testing.assert_array_equal(read_grey(path), 255 - eight)
    np.testing.assert_array_equal(read_grey(path), cv2.imread(str(path), cv2.IMREAD_UNCHANGED))


# --- 8-bit copies ----------------------------------------------------------------------------------------------

def test_eight_bit_copies_scale_by_the_data_range(speckle12):
    reference = to_uint8(speckle12)
    assert reference.dtype == np.uint8
    assert reference.min() == 0 and reference.max() == 255
    assert np.unique(reference).size > 200          # (the top 8 of 16 bits would leave 16 levels)
    for variant in (speckle12 << 4, speckle12.astype(np.float32) / 4095, speckle12.astype(np.float64) * 0.0625):
        assert np.abs(to_uint8(variant).astype(int) - reference).max() <= 1
    eight = (speckle12 >> 4).astype(np.uint8)
    assert to_uint8(eight) is eight
    assert not to_uint8(np.full((4, 4), 7.0)).any()
    with_nan = speckle12.astype(float)
    with_nan[:2] = np.nan
    assert to_uint8(with_nan)[:2].max() == 0 and to_uint8(with_nan)[2:].max() == 255
    with pytest.raises(ValueError, match="cannot make an 8-bit image of complex"):
        to_uint8(np.zeros((3, 3), complex))


def test_sift_input_keeps_256_levels_for_12_bit_and_unit_float_images(speckle12):
    from measurement.stereo_dic import _as_uint8

    reference = _as_uint8(speckle12)
    assert np.unique(reference).size > 200
    for variant in (speckle12 << 4, speckle12.astype(np.float32) / 4095):
        assert np.abs(_as_uint8(variant).astype(int) - reference).max() <= 1


# --- tiny rendered images -------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["paper", "scheimpflug"])
def test_a_scale_giving_tiny_images_warns(name):
    from workbench.rigs import get_rig

    with pytest.warns(UserWarning, match=r"renders 25 x 21 px images, below 100 px on a side"):
        rig = get_rig(name, 0.01)
    assert (rig.left.width, rig.left.height) == (25, 21)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rig = get_rig(name, 0.05)
    assert min(rig.left.width, rig.left.height) >= 100
