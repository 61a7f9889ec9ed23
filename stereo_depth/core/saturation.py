"""Glare: saturated, textureless areas, where any match is noise (a window, a lamp, a shiny floor).

A pixel at the camera's full scale says only "at least this bright": inside a saturated area every
window looks alike, so a matcher's disparity there is arbitrary, and in a costmap it becomes a false
obstacle or a false clearing. The rule, in one place (the `invalidate_saturated` stage and the
clearing cloud both use it): a pixel is glare when it lies in a 9x9 block of saturated pixels (every
channel at full scale: white, as the grey image the matcher sees) of the matched, rectified image at the
camera's own values. Smaller patches are left alone: a glint, a thin bright line or the white squares of
a calibration board still match by the texture around them, which the matching window and the
semi-global paths carry across (on KITTI's sunlit frames a 3x3 block with a one-pixel ring took 2x the
correct matches a 9x9 block takes). Full scale is 255 for 8-bit images and the sensor's
(`saturation_level`: 1023 for a 10-bit, 4095 for a 12-bit sensor in a 16-bit container) for 16-bit
ones, never the frame's own peak, which every frame has.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from stereo_depth.core.camera import StereoCamera
    from stereo_depth.core.matching import MatchResult

TEXTURELESS = np.ones((9, 9), np.uint8)  # a saturated area is made of such blocks


def full_scale(dtype: np.dtype, saturation_level: int) -> int | None:
    """The value at which a pixel of this type saturates: 255 for 8-bit, `saturation_level` (0: 65535) for
    16-bit; None for other types (floating point has no full scale)."""
    if dtype == np.uint8:
        return 255
    if dtype == np.uint16:
        return saturation_level or 65535
    return None


def saturated(image: np.ndarray, top: int) -> np.ndarray:
    """Pixels with every channel at or above `top`."""
    at_top = image >= top
    return at_top if image.ndim == 2 else at_top.all(axis=2)


def glare_area(saturated_pixels: np.ndarray) -> np.ndarray:
    """The glare of a saturation map (bool): the pixels of its saturated 9x9 blocks (a morphological
    opening)."""
    return cv2.morphologyEx(saturated_pixels.view(np.uint8), cv2.MORPH_OPEN, TEXTURELESS) > 0


def rectified_glare(
    raw: np.ndarray,
    rectified: np.ndarray | None,
    camera: StereoCamera | None,
    side: str,
    shape: tuple[int, ...],
    saturation_level: int,
) -> np.ndarray | None:
    """The glare of one input image (any channels, at the camera's bit depth) in the rectified image of
    `shape` the matcher sees; None where the image has none. `rectified`: that image rectified at its own
    values when the caller has it (8-bit grey: the matcher's own), else it is rectified here with `camera`
    (None: the input is rectified already)."""
    top = full_scale(raw.dtype, saturation_level)
    if top is None or int(raw.max(initial=0)) < top:  # interpolation never exceeds its inputs
        return None
    if rectified is None:
        rectified = camera.rectify(raw, side) if camera is not None else raw
    at_top = saturated(rectified, top)
    if at_top.shape[:2] != shape[:2]:  # downsample: a matched pixel is saturated where its whole block is
        levels = at_top.view(np.uint8) * np.uint8(255)
        at_top = cv2.resize(levels, (shape[1], shape[0]), interpolation=cv2.INTER_AREA) == 255
    return glare_area(at_top)


def seen_in_right(disparity: np.ndarray, right_glare: np.ndarray) -> np.ndarray:
    """Left pixels whose match in the right image (x - d, to the nearest pixel) is glare there."""
    seen = np.zeros(disparity.shape, bool)
    rows = np.flatnonzero(right_glare.any(axis=1))
    if rows.size == 0:
        return seen
    width = disparity.shape[1]
    with np.errstate(invalid="ignore"):  # NaN: not matched, sees nothing
        columns = np.rint(np.arange(width, dtype=np.float32) - disparity[rows])
        inside = (columns >= 0) & (columns < width)
    columns = np.where(inside, columns, 0).astype(np.intp)
    seen[rows] = np.take_along_axis(right_glare[rows], columns, axis=1) & inside
    return seen


def invalidate_glare(match: MatchResult, left_glare: np.ndarray | None, right_glare: np.ndarray | None) -> None:
    """No disparity where the left pixel is glare or its match in the right image is: such pixels join
    `match.excluded`, so no later filter refills them."""
    glare = left_glare
    if right_glare is not None:
        seen = seen_in_right(match.disparity, right_glare)
        glare = seen if glare is None else glare | seen
    if glare is None:
        return
    match.disparity[glare] = np.nan
    if match.confidence is not None:
        match.confidence[glare] = 0.0
    match.excluded = glare if match.excluded is None else match.excluded | glare
