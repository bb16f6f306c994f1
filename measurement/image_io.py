"""Reading grey images from files, the one loader for checkerboard detection as for DIC; 8-bit copies for the
consumers that need them.

:func:`read_grey` returns a 2-D array in the file's own dtype (uint8, uint16, other integers, float32/float64):
no value is rescaled or rounded. :func:`read_grey_info` returns the same array with what the data say about
it (:class:`ImageInfo`): the bits actually used (12-bit camera data in a 16-bit container, aligned to the low
or to the high bits), the value range. :func:`to_uint8` makes the 8-bit copy that OpenCV's checkerboard
detector and SIFT need, scaled by the data's own range (not by the container's 65535 or by 255).

What is refused, with a ``ValueError`` that names the file: a missing file, a directory, an empty, truncated
or unreadable file, a multi-page (or animated) file (a stack of 3 or 4 frames that tifffile stored as one planar
RGB(A) page included), a 2-channel image whose second channel is not declared
alpha, more than 4 channels, complex or non-numeric samples. What is converted: colour (3 channels, or 4 with
alpha) to grey with OpenCV's weights (0.299 R + 0.587 G + 0.114 B); an alpha channel is dropped, with a warning
when it is not fully opaque (2-channel grey + alpha included); bilevel (1-bit) images to uint8 0/255; float16
to float32.
"""
from __future__ import annotations

import io
import logging
import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

#: Largest image accepted, pixels (a header claiming more is corrupt for a camera image; OpenCV's own limit).
MAX_PIXELS = 1 << 30

_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
# RGB -> grey weights of OpenCV (ITU-R BT.601), in R, G, B order.
_GREY_WEIGHTS_RGB = np.array([0.299, 0.587, 0.114])


@dataclass(frozen=True, eq=False)
class ImageInfo:
    """A grey image as read from a file, and what its values say about it.

    Attributes
    ----------
    path : Path
    image : ndarray, shape (rows, cols)
        The grey image in the file's own dtype (see :func:`read_grey`).
    container_bits : int or None
        Bits per sample of the dtype (8, 16, 32, ...); None for floating point.
    bits : int or None
        Bits the data use: for integers, the bit length of the largest magnitude less the low bits that are
        zero in every pixel (12 for 12-bit data in a 16-bit container, whether stored as 0..4095 or shifted
        to the high bits as multiples of 16); None for floating point or an all-zero image.
    low_zero_bits : int
        Low bits that are zero in every pixel (4 for 12-bit data aligned to the high bits of 16); 0 for floats.
    value_range : (float, float)
        Smallest and largest finite value (NaN, NaN if there is none).
    non_finite : int
        Number of NaN or infinite pixels (floating point only).
    colour : bool
        The file held colour (RGB or RGBA, decoded by OpenCV), converted to grey with OpenCV's weights.
    """

    path: Path
    image: np.ndarray
    container_bits: int | None
    bits: int | None
    low_zero_bits: int
    value_range: tuple[float, float]
    non_finite: int = 0
    #: True when the file held colour (3 or 4 channels) that was converted to grey.
    colour: bool = False

    def describe(self) -> str:
        """One line for reports, e.g. ``12-bit data in a 16-bit container (values 0..4095)``."""
        low, high = self.value_range
        if self.container_bits is None:
            text = f"{self.image.dtype} floating-point data (values {low:.6g}..{high:.6g})"
            if self.non_finite:
                text += f", {self.non_finite} non-finite pixels"
            return text
        if self.bits is None:
            return f"{self.container_bits}-bit container holding only zeros"
        aligned = f", in the high bits (multiples of {2 ** self.low_zero_bits})" if self.low_zero_bits else ""
        return (f"{self.bits}-bit data in a {self.container_bits}-bit container{aligned} "
                f"(values {int(low)}..{int(high)})")


def read_grey(path: str | Path) -> np.ndarray:
    """Read an image file as a 2-D grey array in its own dtype (uint8, uint16, other integers or float).

    Values are never rescaled or rounded (12-bit data in a 16-bit file stays 0..4095 or 0..65520; a float
    TIFF keeps its floats). Conversions and refusals: see the module docstring; every error is a
    ``ValueError`` naming the file. :func:`read_grey_info` also says how many bits the data use.
    """
    return read_grey_info(path).image


def read_grey_info(path: str | Path) -> ImageInfo:
    """:func:`read_grey` and what the values say: bits used, container, range (:class:`ImageInfo`)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a directory, not an image file")
    if not path.exists():
        raise ValueError(f"image file not found: {path}")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ValueError(f"cannot read image {path}: {err.strerror or err}") from None
    if not data:
        raise ValueError(f"cannot read image {path}: the file is empty (0 bytes)")
    if data[:4] in _TIFF_SIGNATURES:
        image = _decode_tiff(data, path)
    else:
        image = _decode_opencv(data, path)
    colour = np.ndim(image) == 3 and np.shape(image)[2] >= 3
    image = _to_grey(image, path)
    info = _info(path, image)
    return replace(info, colour=True) if colour else info


# ---------------------------------------------------------------------------------------------------------

def _decode_opencv(data: bytes, path: Path, expected_pages: int | None = None) -> np.ndarray:
    """All pages of a file by OpenCV (PNG, BMP, JPEG, PNM, WebP, GIF, ...); exactly one page is accepted.

    Colour comes back in OpenCV's BGR(A) order."""
    buffer = np.frombuffer(data, dtype=np.uint8)
    level = _quiet_opencv()
    try:
        ok, pages = cv2.imdecodemulti(buffer, cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        raise ValueError(f"cannot read image {path}: {_first_line(err)}") from None
    finally:
        _restore_opencv(level)
    if not ok or not pages:
        raise ValueError(f"cannot read image {path}: not an image format OpenCV can decode, or a corrupt or "
                         f"truncated file")
    if len(pages) > 1 and expected_pages is None:
        raise ValueError(f"image {path} holds {len(pages)} pages/frames; expected one grey image (save one "
                         f"image per file)")
    return pages[0]


def _decode_tiff(data: bytes, path: Path) -> np.ndarray:
    """A single-page TIFF by tifffile (any sample type, channel layout and alpha declaration), or by OpenCV
    where tifffile lacks the codec (LZW, JPEG: ``imagecodecs`` not installed) and OpenCV's result has the
    page's dtype and channels. Colour comes back in RGB(A) order, channels last; alpha is dropped here."""
    import tifffile

    # tifffile logs what it finds wrong (a bad page offset, ...); the ValueError below says it for the file.
    tiff_log = logging.getLogger("tifffile")
    previous_level = tiff_log.level
    tiff_log.setLevel(logging.CRITICAL)
    try:
        with tifffile.TiffFile(io.BytesIO(data)) as tif:
            pages = [p for p in tif.pages if not getattr(p, "is_reduced", False)]
            if len(pages) != 1:
                raise _Refused(f"image {path} holds {len(pages)} pages; expected one grey image (split the "
                               "stack into one file per image)" if pages else
                               f"cannot read image {path}: no readable page (a truncated or corrupt TIFF)")
            page = pages[0]
            first_page = page is tif.pages[0]    # what OpenCV would decode
            shape, dtype, axes = tuple(page.shape), np.dtype(page.dtype), str(page.axes)
            bits_per_sample = int(page.bitspersample)
            photometric = int(page.photometric) if page.photometric is not None else -1
            extrasamples = tuple(int(e) for e in (page.extrasamples or ()))
            _refuse_stack_stored_as_planes(page, path, shape, axes, photometric)
            pixels = math.prod(n for n, a in zip(shape, axes) if a in "YX")
            if pixels > MAX_PIXELS or math.prod(shape) > 4 * MAX_PIXELS:
                raise _Refused(f"cannot read image {path}: its header claims {shape} samples (corrupt?)")
            # (bits per sample, not the dtype: bilevel pages pack 8 pixels a byte)
            if int(page.compression) == 1 and math.prod(shape) * bits_per_sample > 8 * len(data):
                raise _Refused(f"cannot read image {path}: the file is truncated (its header claims {shape} "
                               f"uncompressed samples of {dtype}, more than the file's {len(data)} bytes)")
            try:
                image = page.asarray()
                decoded_by = "tifffile"
            except Exception as err:  # noqa: BLE001 - missing codecs and corrupt data raise many types
                image, decoded_by = None, f"{type(err).__name__}: {_first_line(err)}"
    except _Refused as err:
        raise ValueError(str(err)) from None
    except Exception as err:  # noqa: BLE001 - tifffile raises many types for corrupt files
        raise ValueError(f"cannot read image {path}: {_first_line(err)}") from None
    finally:
        tiff_log.setLevel(previous_level)
    if image is None:
        return _tiff_by_opencv(data, path, shape, dtype, axes, decoded_by, strict=True, first_page=first_page)
    image = np.asarray(image)
    if image.shape != shape:
        raise ValueError(f"cannot read image {path}: decoded {image.shape} samples, its header says {shape}")
    # Samples last: tifffile gives (S, Y, X) for planar storage.
    if "S" in axes and image.ndim == len(axes):
        image = np.moveaxis(image, axes.index("S"), -1)
    elif image.ndim != 2:
        raise ValueError(f"image {path} has axes {axes!r} {image.shape}; expected a single grey image")
    if photometric not in (0, 1, 2):
        # PALETTE (indices into a colour map), YCbCr, CMYK, ...: OpenCV converts them itself.
        return _tiff_by_opencv(data, path, shape, dtype, axes, f"photometric {photometric}", strict=False,
                               first_page=first_page)
    grey = photometric in (0, 1)    # MINISWHITE or MINISBLACK
    channels = 1 if image.ndim == 2 else image.shape[2]
    if grey and channels == 2 or photometric == 2 and channels == 4:
        alpha_declared = bool(extrasamples) and extrasamples[-1] in (1, 2)
        if not alpha_declared:
            raise ValueError(f"image {path} has {channels} samples per pixel and the last one is not declared "
                             f"alpha; expected grey, grey + alpha, RGB or RGBA")
        image = _drop_alpha(image, path)
    elif grey and channels != 1:
        raise ValueError(f"image {path} has {channels} samples per pixel; expected grey, grey + alpha, RGB or "
                         "RGBA")
    elif photometric == 2 and channels != 3:
        raise ValueError(f"image {path} is RGB with {channels} samples per pixel; expected 3 (RGB) or 4 (RGBA)")
    if photometric == 0:   # MINISWHITE: 0 is white
        image = _invert_miniswhite(image, bits_per_sample, path)
    if image.ndim == 3:
        return _rgb_to_grey(image)
    return image


def _tiff_by_opencv(data: bytes, path: Path, shape, dtype, axes, why: str, strict: bool,
                    first_page: bool) -> np.ndarray:
    """A TIFF that tifffile could not decode or convert, by OpenCV. ``strict`` (tifffile failed, e.g. for lack
    of a codec): OpenCV's result is accepted only with the page's dtype and channel count, since OpenCV
    silently makes 8-bit grey of layouts it does not know. Otherwise (a palette or other colour space that
    OpenCV converts itself to grey or BGR) any result is accepted. OpenCV reads the first page: a file whose
    image is not its first page (a thumbnail first) is refused rather than read as its thumbnail."""
    if not first_page:
        raise ValueError(f"cannot read image {path}: {why}")
    try:
        image = _decode_opencv(data, path, expected_pages=1)
    except ValueError:
        raise ValueError(f"cannot read image {path}: {why}") from None
    if strict:
        channels = 1 if image.ndim == 2 else image.shape[2]
        expected_channels = shape[axes.index("S")] if "S" in axes else 1
        if image.dtype != dtype or channels != expected_channels:
            raise ValueError(f"cannot read image {path}: tifffile cannot decode it ({why}) and OpenCV reads "
                             f"{channels} channel(s) of {image.dtype}, not the file's {expected_channels} of {dtype}")
    return _bgr_to_grey(image, path)


class _Refused(Exception):
    pass


def _refuse_stack_stored_as_planes(page, path: Path, shape: tuple, axes: str, photometric: int) -> None:
    """A stack of 3 or 4 frames that tifffile stored as one planar RGB(A) page: refused, not mixed to grey.

    ``tifffile.imwrite(path, np.stack([f0, f1, f2]))`` guesses colour for a (3, H, W) or (4, H, W) array and
    writes ONE page of separate R, G, B (, A) planes with its shape metadata ``{"shape": [3, H, W]}``; read as
    colour it would silently become a weighted mean of the frames. Camera software writes colour interleaved
    (contiguous), so a tifffile-written planar colour page whose planes come first is taken for the stack it
    almost always is."""
    if photometric != 2 or int(getattr(page, "planarconfig", 1) or 1) != 2 or not axes.startswith("S"):
        return
    description = str(getattr(page, "description", "") or "")
    if not description.startswith("{") or '"shape"' not in description:
        return                                   # not tifffile's shaped metadata: a colour image of another writer
    planes = shape[0]
    raise _Refused(f"image {path} holds {planes} pages (planes of {shape[2]} x {shape[1]} px that tifffile stored as "
                   f"one planar RGB{'A' if planes == 4 else ''} page, as it does for a stack of {planes} frames "
                   f"saved without photometric='minisblack'); expected one grey image: save one image per file, "
                   f"or a colour image interleaved (planarconfig='contig')")


def _invert_miniswhite(image: np.ndarray, bits_per_sample: int, path: Path) -> np.ndarray:
    if image.dtype == bool:
        return ~image
    if image.dtype.kind == "u":
        white = np.asarray(min(2 ** bits_per_sample - 1, np.iinfo(image.dtype).max), dtype=image.dtype)
        return white - np.minimum(image, white)
    raise ValueError(f"image {path} stores {image.dtype} samples with 0 meaning white; expected unsigned integers")


def _drop_alpha(image: np.ndarray, path: Path) -> np.ndarray:
    """The colour (or grey) channels of an image whose last channel is alpha; warns if alpha is not opaque."""
    alpha = image[..., -1]
    if image.dtype == bool:
        opaque = True
    elif image.dtype.kind in "ui":
        opaque = np.iinfo(image.dtype).max
    else:
        opaque = 1.0
    if not np.all(alpha == opaque):
        warnings.warn(f"image {path}: its alpha channel is not fully opaque and is ignored (the grey "
                      "levels are used as they are)", stacklevel=2)
    rest = image[..., :-1]
    return rest[..., 0] if rest.shape[-1] == 1 else rest


def _bgr_to_grey(image: np.ndarray, path: Path) -> np.ndarray:
    """OpenCV's decoded image (grey, BGR or BGRA) as grey."""
    if image.ndim == 2:
        return image
    channels = image.shape[2]
    if channels == 4:
        image = _drop_alpha(image, path)
    elif channels != 3:
        raise ValueError(f"image {path} has {channels} channels; expected grey, BGR or BGRA")
    return _rgb_to_grey(image[..., ::-1])


def _rgb_to_grey(rgb: np.ndarray) -> np.ndarray:
    """Grey (0.299 R + 0.587 G + 0.114 B) of an RGB image: OpenCV's rounding for 8/16-bit and float32, exact
    double precision for the other sample types."""
    rgb = np.ascontiguousarray(rgb)
    if rgb.dtype in (np.uint8, np.uint16, np.float32):
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return rgb.astype(np.float64) @ _GREY_WEIGHTS_RGB


def _to_grey(image: np.ndarray, path: Path) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 3:
        image = _bgr_to_grey(image, path)   # reached only by OpenCV's output
    if image.ndim != 2:
        raise ValueError(f"image {path} has shape {image.shape}; expected a 2-D grey image")
    if image.size == 0:
        raise ValueError(f"image {path} is empty ({image.shape[1]} x {image.shape[0]} px)")
    if image.dtype == bool:
        return image.astype(np.uint8) * np.uint8(255)
    if image.dtype == np.float16:
        return image.astype(np.float32)
    if image.dtype.kind not in "uif":
        raise ValueError(f"image {path} has {image.dtype} samples; expected integer or real grey levels")
    return np.ascontiguousarray(image)


def _info(path: Path, image: np.ndarray) -> ImageInfo:
    if image.dtype.kind == "f":
        finite = np.isfinite(image)
        count = int(image.size - np.count_nonzero(finite))
        values = image[finite] if count else image
        value_range = (float(values.min()), float(values.max())) if values.size else (np.nan, np.nan)
        return ImageInfo(path, image, None, None, 0, value_range, count)
    low, high = int(image.min()), int(image.max())
    magnitude = max(abs(low), abs(high))
    if magnitude == 0:
        return ImageInfo(path, image, image.dtype.itemsize * 8, None, 0, (float(low), float(high)))
    # Low bits zero in every pixel: OR all values together, count its trailing zeros.
    magnitudes = image if image.dtype.kind == "u" else np.abs(image.astype(np.int64))
    combined = int(np.bitwise_or.reduce(magnitudes, axis=None))
    low_zero = (combined & -combined).bit_length() - 1
    bits = magnitude.bit_length() - low_zero + (1 if low < 0 else 0)
    return ImageInfo(path, image, image.dtype.itemsize * 8, bits, low_zero, (float(low), float(high)))


def to_uint8(image: np.ndarray, percentiles: tuple[float, float] = (0.1, 99.9)) -> np.ndarray:
    """An 8-bit copy of a grey image for consumers that need 8 bits (OpenCV's checkerboard detector, SIFT).

    uint8 images are returned as they are. Anything else (12-bit data in 16 bits, floats in [0, 1] or in
    grey levels, signed integers) is scaled by its own range: the ``percentiles`` of its finite values map
    to 0 and 255 (0.1 / 99.9 % by default, so a few hot or dead pixels do not squeeze the scale), values
    beyond are clipped, NaN and inf become 0. A constant image gives zeros.
    """
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return image
    if image.dtype == bool:
        return image.astype(np.uint8) * np.uint8(255)
    if not (np.issubdtype(image.dtype, np.number) and not np.iscomplexobj(image)):
        raise ValueError(f"cannot make an 8-bit image of {image.dtype} values")
    values = image.astype(np.float64, copy=False)
    finite = np.isfinite(values)
    all_finite = bool(finite.all())
    sample = values if all_finite else values[finite]
    if sample.size == 0:
        return np.zeros(image.shape, dtype=np.uint8)
    low, high = np.percentile(sample, percentiles)
    span = float(high - low)
    if not span > 0:
        return np.zeros(image.shape, dtype=np.uint8)
    scaled = (values - low) * (255.0 / span)
    if not all_finite:
        scaled = np.where(finite, scaled, 0.0)
    return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)


# OpenCV prints its own [ERROR] lines for undecodable files before returning nothing; the ValueError says it.
def _quiet_opencv():
    try:
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        return level
    except AttributeError:
        return None


def _restore_opencv(level) -> None:
    if level is not None:
        cv2.utils.logging.setLogLevel(level)


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__
