"""`mask_image`: the image that says where nothing may be output, read once per file version."""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.errors import ParameterError


def read_mask(path: str) -> np.ndarray:
    """The mask image as bool (True: may be output), read once per file version."""
    try:
        stat = Path(path).stat()
    except OSError as exc:
        msg = f"mask_image {path}: cannot read it ({exc.strerror})"
        raise ParameterError(msg) from exc
    return _read_mask(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=4)
def _read_mask(path: str, mtime_ns: int, size: int) -> np.ndarray:
    del mtime_ns, size  # the cache key: a changed file is read again
    image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if image is None:
        msg = f"mask_image {path}: not an image OpenCV can read (use a PNG, zero where nothing is output)"
        raise ParameterError(msg)
    mask: np.ndarray = image > 0
    mask.setflags(write=False)
    return mask
