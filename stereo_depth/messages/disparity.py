"""stereo_msgs/DisparityImage <-> the core's disparity (float32, NaN invalid)."""

from __future__ import annotations

from typing import Any

import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.errors import ImageError
from stereo_depth.messages.common import MessageBuffer, MessageTypes, in_serialized_bytes
from stereo_depth.messages.images import ENCODINGS, _image_with_data, image_to_array


def disparity_to_msg(
    types: MessageTypes,
    header: Any,
    disparity: np.ndarray,
    camera: StereoCamera,
    min_disparity: int,
    disparity_range: int,
    valid_window: tuple[int, int, int, int],
    delta_d: float = 1.0 / 16.0,
    buffer: MessageBuffer | None = None,
) -> Any:
    """stereo_msgs/DisparityImage as stereo_image_proc users read it (its image data in `buffer`'s bytes
    when given, see MessageBuffer).

    The image holds d' = x_l - x_r - (cx_l - cx_r), so Z = f * t / d' with no further offset;
    min/max_disparity are offset the same way, and invalid pixels (NaN) hold min_disparity - 1. Valid
    ones are not below min_disparity - 1 (a reader takes any value below min_disparity as invalid), so
    one `fmax`, which passes over NaN, puts that value in.
    """
    offset = np.float32(camera.disparity_offset)
    min_d = float(min_disparity) - float(offset)
    height, width = disparity.shape
    x, y, w, h = valid_window

    def message(data: Any) -> Any:
        return types.DisparityImage(
            header=header,
            image=_image_with_data(types, header, data, height, width, "32FC1", width * 4),
            f=float(camera.fx),
            t=float(camera.baseline),
            valid_window=types.RegionOfInterest(x_offset=x, y_offset=y, height=h, width=w, do_rectify=False),
            min_disparity=min_d,
            max_disparity=min_d + float(disparity_range) - 1.0,
            delta_d=float(delta_d),
        )

    buffer = buffer or MessageBuffer()
    serialized = in_serialized_bytes(types, message, height * width * 4, buffer)
    if serialized is None:
        data = buffer.get(types, ("32FC1", height, width), height * width * 4)
        msg, image = message(data), np.frombuffer(data, np.float32).reshape(height, width)
    else:  # the serialized message (rclpy)
        msg, image = serialized[0], serialized[1].view(np.float32).reshape(height, width)
    invalid = np.float32(min_d - 1.0)
    if offset:  # computed straight into the message
        np.subtract(disparity, offset, out=image, dtype=np.float32)
        np.fmax(image, invalid, out=image)
    else:  # the usual calibration (cx_l = cx_r): one pass over the frame, not two
        np.fmax(disparity, invalid, out=image, dtype=np.float32)
    return msg


def disparity_from_msg(msg: Any) -> np.ndarray:
    """The offset-adjusted disparity (Z = f * t / d) as float32 with NaN for invalid pixels.

    An image with no encoding is read as 32FC1, what DisparityImage documents, when its step and size
    fit (stereo_image_proc reads it as float whatever the encoding says; its own test fixture sets none)."""
    encoding = str(msg.image.encoding)
    if encoding and encoding not in ENCODINGS:
        text = f"disparity image encoding '{encoding}' is not supported; a DisparityImage holds 32FC1 (float pixels)"
        raise ImageError(text)
    try:
        pixels = image_to_array(msg.image, encoding=encoding or "32FC1")
    except ImageError as exc:
        if encoding:
            raise
        text = f"disparity image has an empty encoding and does not fit 32FC1 ({exc}); publish it as 32FC1"
        raise ImageError(text) from exc
    image = pixels.astype(np.float32, copy=True)
    image[~(image >= msg.min_disparity)] = np.nan
    return image
