"""The twin's inputs, read and checked: calibration, images, region of interest.

Every refusal is a ``ValueError`` naming the file or option at fault and saying what to do:

* a calibration whose image size is not the images' (with both sizes);
* an image whose data use more bits than ``--bit-depth`` claims, or a claim above the file's container
  (a colour file is converted to grey with OpenCV's weights, which is said; claiming 16 bits for it is refused);
* an image saturated over a large part of the ROI (:data:`MAX_SATURATED_FRACTION`; a smaller part is a warning);
* a static image of another size than its reference.

A static pair that is not static is found after the instrument has measured it (:mod:`workbench.twin.run`).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from measurement.image_io import ImageInfo, read_grey_info
from measurement.speckle_quality import grey_statistics

from ..rigs import rig_from_calibration

#: An image with more than this fraction of its ROI at the sensor's ceiling is refused: clipped subsets carry no
#: texture and the noise there is not the camera's.
MAX_SATURATED_FRACTION = 0.05
#: Above this fraction (and up to the refusal) a warning is given.
WARN_SATURATED_FRACTION = 0.005
#: Bit depths a claim may take.
BIT_DEPTHS = (8, 10, 12, 14, 16)


@dataclass
class TwinInputs:
    """Checked inputs of a twin (module notes).

    Attributes
    ----------
    images : dict
        ``{"left", "right", "static_left", "static_right"}`` -> float64 grey arrays (present ones only).
    infos : dict
        The same keys -> :class:`measurement.image_io.ImageInfo`.
    bit_depth : int
        Bits of the data (claimed, or read from the left reference).
    rig : StereoRig or None
        The user's rig from their calibration file (None: a one-camera twin in pixels).
    calibration : Path or None
    roi : (x0, y0, x1, y1) or None
    mask : ndarray of bool or None
        User's mask (left reference pixels to measure).
    region : ndarray of bool
        ROI and mask together: the pixels whose statistics describe the speckle.
    notes : list of str
        What was converted or assumed (colour to grey, bits read from the data, ...).
    """

    images: dict
    infos: dict
    bit_depth: int
    rig: object
    calibration: Path | None
    roi: tuple | None
    mask: np.ndarray | None
    region: np.ndarray = field(repr=False)
    notes: list = field(default_factory=list)

    @property
    def stereo(self) -> bool:
        return "right" in self.images

    @property
    def has_static(self) -> bool:
        return "static_left" in self.images


def _bits_of(info: ImageInfo) -> int:
    if info.container_bits is None:
        raise ValueError(f"{info.path}: floating-point images have no bit depth; give integer camera images")
    return int(info.bits or 8)


def check_bit_depth(info: ImageInfo, claim: int | None, option: str = "--bit-depth") -> int:
    """The bit depth of an image's data, checked against a claim (see the module notes)."""
    bits = _bits_of(info)
    if claim is None:
        # 8-bit data in a 16-bit container is rare; camera data in 16 bits use 10-16 of them.
        if info.container_bits == 8:
            return 8
        return next((b for b in BIT_DEPTHS if b >= bits), 16)
    if claim not in BIT_DEPTHS:
        raise ValueError(f"{option} {claim}: give one of {', '.join(map(str, BIT_DEPTHS))}")
    if info.colour and claim > 8:
        raise ValueError(f"{info.path}: a colour image (8 bits per channel, converted to 8-bit grey) cannot hold "
                         f"{claim}-bit data as {option} {claim} claims")
    if claim > info.container_bits:
        raise ValueError(f"{info.path} is a {info.container_bits}-bit file ({info.describe()}) but {option} claims "
                         f"{claim}-bit data")
    if bits > claim:
        raise ValueError(f"{info.path} holds {info.describe()} but {option} claims {claim}-bit data: give "
                         f"{option} {next((b for b in BIT_DEPTHS if b >= bits), 16)} (or none, to read it from "
                         "the data)")
    return int(claim)


def parse_roi(text: str | None) -> tuple[int, int, int, int] | None:
    """``'X0,Y0,X1,Y1'`` (px, x1/y1 exclusive) -> tuple; None for None or ''."""
    if not text:
        return None
    parts = text.split(",")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        raise ValueError(f"--roi {text!r}: give X0,Y0,X1,Y1 as integers (px)") from None
    if len(values) != 4 or values[2] <= values[0] or values[3] <= values[1] or min(values) < 0:
        raise ValueError(f"--roi {text!r}: give X0,Y0,X1,Y1 with X1 > X0 >= 0 and Y1 > Y0 >= 0")
    return values


def region_of(shape: tuple[int, int], roi, mask) -> np.ndarray:
    """The pixels of the ROI rectangle and the mask (the whole image without either)."""
    region = np.ones(shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool).copy()
    if roi is not None:
        x0, y0, x1, y1 = roi
        rect = np.zeros(shape, dtype=bool)
        rect[y0:y1, x0:x1] = True
        region &= rect
    if not region.any():
        raise ValueError("the ROI and mask select no pixel of the left reference image")
    return region


def load_inputs(left, right=None, static_left=None, static_right=None, *, calibration=None, roi=None,
                mask=None, bit_depth: int | None = None) -> TwinInputs:
    """Read and check a twin's files (module notes).

    Parameters
    ----------
    left, right, static_left, static_right : path
        Reference images of the left (and right) camera, and a second exposure of each of the unmoved scene.
    calibration : path, optional
        The rig's calibration file (any format ``workbench calibration convert`` reads); needed with ``right``.
    roi : (x0, y0, x1, y1) or str, optional
    mask : path or ndarray of bool, optional
        A mask image (non-zero = measure) of the left reference's size, or the array.
    bit_depth : int, optional
        The bits of the data, if the user states them; checked against every image.
    """
    paths = {"left": left, "right": right, "static_left": static_left, "static_right": static_right}
    paths = {k: Path(v) for k, v in paths.items() if v is not None}
    if "right" in paths and calibration is None:
        raise ValueError("a stereo twin (--right) needs the rig's calibration (--calib)")
    if "static_right" in paths and "right" not in paths:
        raise ValueError("--static-right needs --right (the right reference image)")
    if "right" in paths and "static_left" in paths and "static_right" not in paths:
        raise ValueError("a stereo static pair needs --static-right as well as --static-left")
    infos = {k: read_grey_info(p) for k, p in paths.items()}
    notes = []
    depth = check_bit_depth(infos["left"], bit_depth)
    for k, info in infos.items():
        if bit_depth is not None:
            check_bit_depth(info, bit_depth)
        elif check_bit_depth(info, None) > depth:
            raise ValueError(f"{info.path} holds {info.describe()} but the left reference {infos['left'].path} holds "
                             f"{infos['left'].describe()}: all images of a twin come from the same cameras at one "
                             "bit depth")
        if info.colour:
            notes.append(f"{info.path.name} is a colour image, converted to grey (0.299 R + 0.587 G + 0.114 B): "
                         "the noise model is that of the grey conversion")
    if bit_depth is None:
        notes.append(f"bit depth read from the data: {infos['left'].describe()} -> {depth} bits")
    images = {k: np.asarray(info.image, dtype=np.float64) for k, info in infos.items()}
    shape = images["left"].shape
    for k in ("static_left",):
        if k in images and images[k].shape != shape:
            raise ValueError(f"{paths[k]} is {images[k].shape[1]} x {images[k].shape[0]} px but the left reference "
                             f"{paths['left']} is {shape[1]} x {shape[0]} px: a static pair must be the same size")
    if "static_right" in images and images["static_right"].shape != images["right"].shape:
        raise ValueError(f"{paths['static_right']} is {images['static_right'].shape[1]} x "
                         f"{images['static_right'].shape[0]} px but the right reference {paths['right']} is "
                         f"{images['right'].shape[1]} x {images['right'].shape[0]} px")
    rig = None
    if calibration is not None:
        calibration = Path(calibration)
        rig = rig_from_calibration(calibration)
        for k, side in (("left", "left"), ("right", "right")):
            if k not in images:
                continue
            cam = rig.camera(side)
            h, w = images[k].shape
            if (w, h) != (cam.width, cam.height):
                raise ValueError(f"calibration {calibration} is for {cam.width} x {cam.height} px images but the "
                                 f"{side} image {paths[k]} is {w} x {h} px: the calibration does not belong to these "
                                 "images (or they were cropped/binned)")
    roi = parse_roi(roi) if isinstance(roi, str) or roi is None else tuple(int(v) for v in roi)
    if roi is not None and (roi[2] > shape[1] or roi[3] > shape[0]):
        raise ValueError(f"--roi {roi} reaches outside the {shape[1]} x {shape[0]} px left reference image")
    mask_array = None
    if mask is not None:
        if isinstance(mask, (str, Path)):
            mask_array = read_grey_info(mask).image != 0
            where = f"mask {mask}"
        else:
            mask_array = np.asarray(mask, dtype=bool)
            where = "mask"
        if mask_array.shape != shape:
            raise ValueError(f"{where} is {mask_array.shape[1]} x {mask_array.shape[0]} px but the left reference "
                             f"is {shape[1]} x {shape[0]} px")
    region = region_of(shape, roi, mask_array)
    ceiling = 2 ** depth - 1
    for k in ("left", "static_left"):
        if k not in images:
            continue
        stats = grey_statistics(images[k], region, depth)
        if stats.saturated_fraction > MAX_SATURATED_FRACTION:
            raise ValueError(f"{paths[k]}: {100 * stats.saturated_fraction:.1f} % of the ROI is saturated (grey "
                             f"{ceiling}), above {100 * MAX_SATURATED_FRACTION:g} %: clipped subsets carry no texture "
                             "and no noise to predict; shorten the exposure or exclude the glare with --roi/--mask")
        if stats.saturated_fraction > WARN_SATURATED_FRACTION:
            warnings.warn(f"{paths[k]}: {100 * stats.saturated_fraction:.2f} % of the ROI is saturated", stacklevel=2)
            notes.append(f"{paths[k].name}: {100 * stats.saturated_fraction:.2f} % of the ROI saturated")
    return TwinInputs(images, infos, depth, rig, calibration, roi, mask_array, region, notes)
