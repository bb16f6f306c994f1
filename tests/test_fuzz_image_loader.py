"""Property-based fuzzing (hypothesis) of the image loader, :func:`measurement.image_io.read_grey`.

The property: whatever the file holds, ``read_grey`` returns a non-empty 2-D array of real numbers or raises
``ValueError`` whose message names the file -- never another exception (cv2.error, tifffile's errors,
TypeError, IndexError, MemoryError, ...), and never a silently wrong picture: a single grey page written
losslessly reads back exactly. Inputs:

* random small arrays (1-12 x 1-12 px) written by OpenCV (PNG, BMP, TIFF, JPEG, PGM), tifffile (bool to
  complex samples, 1-5 channels, 1-3 pages, contiguous or planar, MINISBLACK / MINISWHITE / RGB, declared or
  undeclared extra samples, raw or deflate) and Pillow (grey + alpha, palette, 16-bit grey, animated PNG/GIF);
* those files cut at a random byte;
* those files with 1-8 random bytes overwritten;
* random bytes, bare or behind the signature of a format (PNG, TIFF, BigTIFF, BMP, JPEG, GIF, PGM, WebP).

Each file gets a random image extension (the loader reads by content). A second test writes only single grey
pages in lossless encodings (integer and float TIFF, PNG, PGM), which must read back exactly. The default
run is deterministic (``derandomize=True``) and sized to ~40 s on 2 cores (:data:`DEFAULT_EXAMPLES` +
:data:`LOSSLESS_EXAMPLES` cases); ``pytest -m fuzz_long`` runs :data:`LONG_EXAMPLES` cases of the mixed
inputs.
"""
from __future__ import annotations

import io
import warnings

import cv2
import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from PIL import Image

from measurement.image_io import read_grey

DEFAULT_EXAMPLES = 3000
LOSSLESS_EXAMPLES = 300
LONG_EXAMPLES = 10_000

_COMMON = dict(deadline=None, derandomize=True, database=None, print_blob=True,
               suppress_health_check=list(HealthCheck))
DEFAULT_SETTINGS = settings(max_examples=DEFAULT_EXAMPLES, **_COMMON)
LONG_SETTINGS = settings(max_examples=LONG_EXAMPLES, **_COMMON)

EXTENSIONS = ("png", "tif", "tiff", "bmp", "jpg", "pgm", "gif", "webp", "PNG", "dat")
SIGNATURES = (b"", b"\x89PNG\r\n\x1a\n", b"II*\x00", b"MM\x00*", b"II+\x00\x08\x00\x00\x00", b"BM",
              b"\xff\xd8\xff", b"GIF89a", b"P5\n", b"RIFF\x00\x00\x00\x00WEBPVP8 ")
TIFF_DTYPES = (bool, np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.float16, np.float32,
               np.float64, np.complex64)


def _array(draw, dtype, shape):
    dtype = np.dtype(dtype)
    if dtype == bool:
        return np.asarray(draw(st.lists(st.booleans(), min_size=int(np.prod(shape)), max_size=int(np.prod(shape)))),
                          dtype=bool).reshape(shape)
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    if dtype.kind in "ui":
        info = np.iinfo(dtype)
        top = draw(st.sampled_from([info.max, 4095, 1023, 255, 1]))
        return rng.integers(max(info.min, -top), min(info.max, top), size=shape, endpoint=True, dtype=dtype)
    values = rng.normal(0, draw(st.sampled_from([1.0, 255.0, 1e30])), size=shape)
    if draw(st.booleans()):
        values.flat[rng.integers(0, values.size)] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    if dtype.kind == "c":
        values = values + 1j * rng.normal(size=shape)
    with np.errstate(over="ignore", invalid="ignore"):
        return values.astype(dtype)


@st.composite
def written_images(draw):
    """(bytes, expected): a small image file; ``expected`` is the exact grey array a correct reader returns for
    a single lossless grey page, else None (no oracle beyond the property)."""
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    writer = draw(st.sampled_from(["opencv", "tifffile", "tifffile", "pillow"]))
    if writer == "opencv":
        fmt = draw(st.sampled_from([".png", ".bmp", ".tif", ".jpg", ".pgm"]))
        dtype = draw(st.sampled_from([np.uint8, np.uint16, np.float32, np.int16]))
        channels = draw(st.sampled_from([1, 3, 4]))
        array = _array(draw, dtype, (h, w) if channels == 1 else (h, w, channels))
        try:
            ok, encoded = cv2.imencode(fmt, array)
        except cv2.error:
            ok = False
        if not ok:
            array = np.nan_to_num(array, nan=0.0, posinf=255, neginf=0).clip(0, 255).astype(np.uint8)
            ok, encoded = cv2.imencode(".png", array)
            fmt = ".png"
        lossless = channels == 1 and (fmt in (".png", ".pgm") and array.dtype in (np.uint8, np.uint16)
                                      or fmt == ".bmp" and array.dtype == np.uint8)
        return encoded.tobytes(), array if lossless else None
    if writer == "pillow":
        kind = draw(st.sampled_from(["LA", "P", "I;16", "L-anim-png", "L-anim-gif", "L"]))
        grey = _array(draw, np.uint8, (h, w))
        buffer = io.BytesIO()
        if kind == "LA":
            Image.fromarray(np.dstack([grey, _array(draw, np.uint8, (h, w))]), "LA").save(buffer, "PNG")
        elif kind == "P":
            Image.fromarray(grey).convert("P").save(buffer, "PNG")
        elif kind == "I;16":
            Image.fromarray(grey.astype(np.uint16) * 257).save(buffer, "PNG")
        elif kind == "L":
            Image.fromarray(grey).save(buffer, "PNG")
        else:
            frames = [Image.fromarray(grey), Image.fromarray(255 - grey)]
            frames[0].save(buffer, "PNG" if kind.endswith("png") else "GIF", save_all=True, append_images=frames[1:])
        expected = grey if kind == "L" else grey.astype(np.uint16) * 257 if kind == "I;16" else None
        return buffer.getvalue(), expected
    dtype = draw(st.sampled_from(TIFF_DTYPES))
    pages = draw(st.sampled_from([1, 1, 1, 2, 3]))
    channels = draw(st.sampled_from([1, 1, 2, 3, 4, 5]))
    photometric = draw(st.sampled_from(["minisblack", "minisblack", "rgb", "miniswhite", None]))
    planar = draw(st.sampled_from(["contig", "separate"]))
    compression = draw(st.sampled_from([None, "zlib"]))
    extrasamples = draw(st.sampled_from([None, "unassalpha", "assocalpha", "unspecified"]))
    shape = (h, w) if channels == 1 else ((channels, h, w) if planar == "separate" else (h, w, channels))
    array = np.stack([_array(draw, dtype, shape) for _ in range(pages)]) if pages > 1 else _array(draw, dtype, shape)
    kwargs = {"photometric": photometric, "compression": compression}
    if channels > 1:
        kwargs["planarconfig"] = planar
        extra = channels - (3 if photometric == "rgb" else 1)
        if extrasamples is not None and extra > 0:
            kwargs["extrasamples"] = [extrasamples] * extra
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            tifffile.imwrite(buffer, array, **kwargs)
        except Exception:  # noqa: BLE001 - an invalid combination: write the array plainly instead
            buffer = io.BytesIO()
            try:
                tifffile.imwrite(buffer, array)
            except Exception:  # noqa: BLE001
                buffer = io.BytesIO()
                tifffile.imwrite(buffer, np.zeros((h, w), np.uint8))
                array, pages, channels, photometric = np.zeros((h, w), np.uint8), 1, 1, "minisblack"
    lossless = (pages == 1 and channels == 1 and photometric in ("minisblack", None) and array.dtype != bool
                and array.dtype.kind in "uif" and array.dtype != np.float16)
    return buffer.getvalue(), array if lossless else None


@st.composite
def image_files(draw):
    """(kind, extension, bytes, expected) over the four input classes."""
    kind = draw(st.sampled_from(["written", "truncated", "damaged", "random"]))
    extension = draw(st.sampled_from(EXTENSIONS))
    if kind == "random":
        return kind, extension, draw(st.sampled_from(SIGNATURES)) + draw(st.binary(max_size=600)), None
    data, expected = draw(written_images())
    if kind == "written":
        return kind, extension, data, expected
    if kind == "truncated":
        return kind, extension, data[:draw(st.integers(0, max(0, len(data) - 1)))], None
    damaged = bytearray(data)
    for _ in range(draw(st.integers(1, 8))):
        damaged[draw(st.integers(0, len(damaged) - 1))] = draw(st.integers(0, 255))
    return kind, extension, bytes(damaged), None


@st.composite
def lossless_grey_pages(draw):
    """(kind, extension, bytes, expected): one grey page in a lossless encoding, to read back exactly."""
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    extension = draw(st.sampled_from(EXTENSIONS))
    if draw(st.booleans()):
        dtype = draw(st.sampled_from([np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.float32,
                                      np.float64]))
        array = _array(draw, dtype, (h, w))
        buffer = io.BytesIO()
        tifffile.imwrite(buffer, array, photometric="minisblack", compression=draw(st.sampled_from([None, "zlib"])))
        return "lossless", extension, buffer.getvalue(), array
    array = _array(draw, draw(st.sampled_from([np.uint8, np.uint16])), (h, w))
    ok, encoded = cv2.imencode(draw(st.sampled_from([".png", ".pgm", ".tif"])), array)
    assert ok
    return "lossless", extension, encoded.tobytes(), array


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz images")


def _check(folder, case):
    kind, extension, data, expected = case
    path = folder / f"case image.{extension}"
    path.write_bytes(data)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            image = read_grey(path)
    except ValueError as err:
        assert str(path) in str(err), f"the error does not name the file: {err}"
        assert expected is None, f"a valid single grey page was refused: {err}"
        event(f"{kind}: refused")
        return "refused"
    assert isinstance(image, np.ndarray) and image.ndim == 2 and image.size > 0, (type(image), image.shape)
    assert image.dtype.kind in "uif", image.dtype
    if expected is not None:
        np.testing.assert_array_equal(image, expected)
        event(f"{kind}: read, checked against the written array")
        return "read back exactly"
    event(f"{kind}: read")
    return "read"


@DEFAULT_SETTINGS
@given(case=image_files())
def test_read_grey_returns_a_grey_image_or_a_value_error_naming_the_file(folder, case):
    assert _check(folder, case) in ("refused", "read", "read back exactly")


@settings(max_examples=LOSSLESS_EXAMPLES, **_COMMON)
@given(case=lossless_grey_pages())
def test_a_lossless_single_grey_page_reads_back_exactly(folder, case):
    assert _check(folder, case) == "read back exactly"


@pytest.mark.fuzz_long
@LONG_SETTINGS
@given(case=image_files())
def test_read_grey_fuzz_long(folder, case):
    assert _check(folder, case) in ("refused", "read", "read back exactly")
