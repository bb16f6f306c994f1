"""Reading grey images from files (8/16-bit PNG/TIFF/BMP/..., float TIFF), with errors that name the file."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def read_grey(path: str | Path) -> np.ndarray:
    """Read an image file as a 2-D grey array in its own dtype (uint8, uint16 or float).

    Colour images are converted to grey (OpenCV's BGR -> grey weights). A clear ValueError names the file
    that cannot be read.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"image file not found: {path}")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None and path.suffix.lower() in (".tif", ".tiff"):
        import tifffile
        try:
            image = tifffile.imread(str(path))
        except Exception as err:  # tifffile raises many types for corrupt files
            raise ValueError(f"cannot read image {path}: {err}") from None
    if image is None:
        raise ValueError(f"cannot read image {path}")
    if image.ndim == 3:
        if image.shape[2] not in (3, 4):
            raise ValueError(f"image {path} has {image.shape[2]} channels; expected grey, BGR or BGRA")
        image = cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_BGR2GRAY)
    if image.ndim != 2:
        raise ValueError(f"image {path} has shape {image.shape}; expected a 2-D grey image")
    return image
