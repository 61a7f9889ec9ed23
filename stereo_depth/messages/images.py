"""sensor_msgs/Image <-> arrays: every encoding, row padding and byte order detail."""

from __future__ import annotations

import sys
from typing import Any

import cv2
import numpy as np

from stereo_depth.errors import ImageError
from stereo_depth.messages.common import DEFAULT_MAX_PIXELS, MessageTypes, _bytes, _with_data, check_pixel_count

# camera encoding -> (dtype, channels, conversion to the pipeline's BGR / mono, or None if used as is)
_BAYER = {
    "bayer_rggb8": cv2.COLOR_BayerRGGB2BGR if hasattr(cv2, "COLOR_BayerRGGB2BGR") else cv2.COLOR_BayerBG2BGR,
    "bayer_bggr8": cv2.COLOR_BayerBGGR2BGR if hasattr(cv2, "COLOR_BayerBGGR2BGR") else cv2.COLOR_BayerRG2BGR,
    "bayer_gbrg8": cv2.COLOR_BayerGBRG2BGR if hasattr(cv2, "COLOR_BayerGBRG2BGR") else cv2.COLOR_BayerGR2BGR,
    "bayer_grbg8": cv2.COLOR_BayerGRBG2BGR if hasattr(cv2, "COLOR_BayerGRBG2BGR") else cv2.COLOR_BayerGB2BGR,
}
CAMERA_ENCODINGS: dict[str, tuple[str, int, int | None]] = {
    "mono8": ("u1", 1, None),
    "8UC1": ("u1", 1, None),
    "mono16": ("u2", 1, None),
    "16UC1": ("u2", 1, None),
    "bgr8": ("u1", 3, None),
    "8UC3": ("u1", 3, None),
    "rgb8": ("u1", 3, cv2.COLOR_RGB2BGR),
    "bgra8": ("u1", 4, cv2.COLOR_BGRA2BGR),
    "rgba8": ("u1", 4, cv2.COLOR_RGBA2BGR),
    "bgr16": ("u2", 3, None),
    "rgb16": ("u2", 3, cv2.COLOR_RGB2BGR),
    **{name: ("u1", 1, code) for name, code in _BAYER.items()},
    **{name.replace("8", "16"): ("u2", 1, code) for name, code in _BAYER.items()},
}
# what we read and write besides camera images (disparity and depth)
ENCODINGS = {**CAMERA_ENCODINGS, "32FC1": ("f4", 1, None)}
_SUPPORTED = "mono8, mono16, bgr8, rgb8, bgra8, rgba8, bayer_* (8 or 16 bit)"


def _unsupported(encoding: str) -> ImageError:
    if not encoding:
        return ImageError("image has an empty encoding; the driver must set e.g. mono8 or bgr8")
    return ImageError(f"image encoding '{encoding}' is not supported for camera images; use one of {_SUPPORTED}")


# ---------------------------------------------------------------- images


def image_to_array(msg: Any, max_pixels: int = DEFAULT_MAX_PIXELS, encoding: str | None = None) -> np.ndarray:
    """A view of the image's pixels, (H, W) or (H, W, C), in native byte order; row padding dropped.
    `encoding`: read the pixels as this instead of the message's own encoding."""
    encoding = encoding or str(msg.encoding)
    if encoding not in ENCODINGS:
        raise _unsupported(encoding)
    dtype_code, channels, _ = ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        msg_text = f"image is {width}x{height}: zero-sized; the driver published an empty image"
        raise ImageError(msg_text)
    check_pixel_count(width, height, max_pixels)
    dtype = np.dtype(dtype_code).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        msg_text = (
            f"image step {step} is smaller than one row of {width} {encoding} pixels ({row_bytes} bytes); "
            "the driver sets a wrong step, width or encoding"
        )
        raise ImageError(msg_text)
    buffer = np.frombuffer(msg.data, dtype=np.uint8)
    if buffer.size != step * height:
        msg_text = (
            f"image data has {buffer.size} bytes but step x height = {step} x {height} = {step * height}; "
            "the message is truncated or the driver sets a wrong step or height"
        )
        raise ImageError(msg_text)
    if step % dtype.itemsize:
        msg_text = (
            f"image step {step} is not a multiple of the {dtype.itemsize}-byte pixel component; "
            "the driver sets a wrong step or encoding"
        )
        raise ImageError(msg_text)
    rows = buffer.reshape(height, step)[:, :row_bytes]
    pixels = rows.view(dtype).reshape(height, width, channels)
    if channels == 1:
        pixels = pixels[:, :, 0]
    if not dtype.isnative:
        pixels = pixels.astype(dtype.newbyteorder("="))
    return pixels


def image_to_pipeline(msg: Any, max_pixels: int = DEFAULT_MAX_PIXELS) -> np.ndarray:
    """Pixels as the pipeline takes them: mono (uint8 or uint16) or BGR uint8."""
    encoding = str(msg.encoding)
    if encoding not in CAMERA_ENCODINGS:
        raise _unsupported(encoding)
    return _to_pipeline(image_to_array(msg, max_pixels), CAMERA_ENCODINGS[encoding][2])


def _to_pipeline(pixels: np.ndarray, code: int | None) -> np.ndarray:
    if code is not None:
        pixels = cv2.cvtColor(pixels, code)
    if pixels.ndim == 3 and pixels.dtype != np.uint8:
        pixels = (pixels >> 8).astype(np.uint8)
    return pixels


def encoding_for(array_: np.ndarray) -> str:
    if array_.dtype == np.float32 and array_.ndim == 2:
        return "32FC1"
    if array_.dtype == np.uint8:
        return "mono8" if array_.ndim == 2 else "bgr8"
    if array_.dtype == np.uint16 and array_.ndim == 2:
        return "mono16"
    msg = f"no image encoding for an array of {array_.dtype} with shape {array_.shape}"
    raise ImageError(msg)


def array_to_image(types: MessageTypes, header: Any, pixels: np.ndarray, encoding: str | None = None) -> Any:
    height, width = pixels.shape[:2]
    step = width * pixels.itemsize * (pixels.shape[2] if pixels.ndim == 3 else 1)
    return _image_with_data(types, header, _bytes(types, pixels), height, width, encoding or encoding_for(pixels), step)


def _image_with_data(
    types: MessageTypes, header: Any, data: Any, height: int, width: int, encoding: str, step: int
) -> Any:
    return _with_data(
        types,
        types.Image,
        data,
        header=header,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=int(sys.byteorder == "big"),
        step=step,
    )
