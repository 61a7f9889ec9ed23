"""image_transport's encodings: `compressed` (JPEG, PNG) images and `compressedDepth` depth images."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from stereo_depth.core.rvl import rvl_compress
from stereo_depth.errors import ImageError
from stereo_depth.messages.common import DEFAULT_MAX_PIXELS, MessageTypes, _bytes, check_pixel_count
from stereo_depth.messages.images import _to_pipeline, encoding_for

# ---------------------------------------------------------------- compressed images (image_transport)

COMPRESSED_FORMATS = ("jpeg", "png")
_JPEG_END = b"\xff\xd9"


def compressed_format(format_: str) -> tuple[str, str]:
    """(codec, encoding of the compressed pixels) from image_transport's format string.

    "bgr8; jpeg compressed bgr8" -> ("jpeg", "bgr8"); plain "jpeg" / "png" -> (codec, ""). The pixels
    are in the order the encoder was given: image_transport hands it BGR for every colour image.
    """
    text = format_.strip().lower()
    _, _, compressed = text.rpartition(";")
    words = compressed.split()
    codec = next((w for w in words if w in COMPRESSED_FORMATS or w == "jpg"), "")
    if codec not in COMPRESSED_FORMATS and codec != "jpg":
        msg = (
            f"compressed image format '{format_}' is not supported; expected image_transport's jpeg or png "
            "('bgr8; jpeg compressed bgr8', 'mono8; png compressed mono8', 'jpeg', 'png')"
        )
        raise ImageError(msg)
    after = words[words.index("compressed") + 1 :] if "compressed" in words else []
    return ("jpeg" if codec == "jpg" else codec), (after[0] if after else "")


def compressed_to_pipeline(msg: Any, max_pixels: int = DEFAULT_MAX_PIXELS) -> np.ndarray:
    """A sensor_msgs/CompressedImage decoded once into pipeline pixels (mono or BGR uint8, mono16 kept).

    cv2.imdecode releases the GIL, so decoding on the node's worker thread does not stall the executor.
    A damaged payload (cut off, or not a JPEG / PNG at all) raises ImageError: the frame is skipped.
    """
    codec, pixel_encoding = compressed_format(str(msg.format))
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if data.size == 0:
        msg_text = f"compressed image ({msg.format}) has no data; the driver published an empty image"
        raise ImageError(msg_text)
    if codec == "jpeg" and data[-2:].tobytes() != _JPEG_END:
        msg_text = (
            f"compressed image ({msg.format}, {data.size} bytes) is a damaged JPEG: it does not end with the "
            "JPEG end marker (cut off in transport or recording)"
        )
        raise ImageError(msg_text)
    pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if pixels is None:
        msg_text = (
            f"compressed image ({msg.format}, {data.size} bytes) cannot be decoded as {codec}: the data is damaged"
        )
        raise ImageError(msg_text)
    height, width = pixels.shape[:2]
    check_pixel_count(width, height, max_pixels)
    code = None
    if pixels.ndim == 3:
        rgb_order = pixel_encoding.startswith("rgb")
        if pixels.shape[2] == 4:
            code = cv2.COLOR_RGBA2BGR if rgb_order else cv2.COLOR_BGRA2BGR
        elif rgb_order:
            code = cv2.COLOR_RGB2BGR
    return _to_pipeline(pixels, code)


def array_to_compressed(types: MessageTypes, header: Any, pixels: np.ndarray, codec: str, quality: int = 95) -> Any:
    """A CompressedImage as image_transport's compressed publisher writes it (format string included;
    colour as BGR, JPEG quality 95 and PNG level 3 are its defaults)."""
    encoding = encoding_for(pixels)
    if codec == "jpeg" and pixels.dtype != np.uint8:
        msg = f"JPEG holds 8-bit images only, not {encoding}; use png"
        raise ImageError(msg)
    params = [cv2.IMWRITE_JPEG_QUALITY, quality] if codec == "jpeg" else [cv2.IMWRITE_PNG_COMPRESSION, 3]
    ok, data = cv2.imencode(".jpg" if codec == "jpeg" else ".png", pixels, params)
    if not ok:
        msg = f"cannot encode a {encoding} image as {codec}"
        raise ImageError(msg)
    return types.CompressedImage(
        header=header, format=f"{encoding}; {codec} compressed {encoding}", data=_bytes(types, data)
    )


# ---------------------------------------------------------------- compressedDepth (image_transport)

COMPRESSED_DEPTH_FORMATS = ("png", "rvl")
_INV_DEPTH = 0  # compressed_depth_image_transport's compressionFormat enum: UNDEFINED = -1, INV_DEPTH
_CONFIG_HEADER = np.dtype([("format", "<i4"), ("depth_param", "<f4", (2,))])  # its ConfigHeader, 12 bytes
RVL_MAX_PIXELS_PER_BYTE = 5  # the most the transport's decoder takes (`rvl_accepted`)
# PNG rows unfiltered: what RVL refuses is mostly runs of zeros, which deflate packs as small unfiltered
# (3.2-3.6 kB at 752x480), and libpng's adaptive filter choice costs 8-15 ms of such a frame, unfiltered 1-2.
# OpenCV 4.6 (the oldest we support) has no such flag: there libpng chooses the filters, same pixels.
_UNFILTERED = (cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE) if hasattr(cv2, "IMWRITE_PNG_FILTER") else ()
RVL_FALLBACK_NOTE = (
    "depth/compressedDepth: a frame of mostly invalid depth packs into fewer RVL bytes than image_transport's "
    "decoder accepts (pixels / 5), so such frames go as PNG; each message's format string names its codec"
)


def depth_to_compressed_depth(
    types: MessageTypes,
    header: Any,
    depth: np.ndarray,
    encoding: str,
    *,
    codec: str = "png",
    depth_max: float = 10.0,
    depth_quantization: float = 100.0,
    png_level: int = 3,
) -> Any:
    """A depth image as image_transport's `compressedDepth` publisher writes it (codec.cpp of
    compressed_depth_image_transport, Jazzy), so its subscriber and every consumer of the transport
    decode it: format "<encoding>; compressedDepth <png|rvl>", then a 12-byte ConfigHeader (int32
    compressionFormat = INV_DEPTH, float32 depthParam[2]), then the PNG or RVL stream.

    32FC1 metres become 16-bit inverse depth q = A / z + B (A = z0 (z0 + 1), B = 1 - A / depth_max,
    z0 = depth_quantization, float32 as the plugin computes it; truncated; 0 for NaN and z >= depth_max;
    saturated at 65535 where the plugin's cast would wrap), and A, B go in depthParam. 16UC1 millimetres
    are kept, 0 beyond depth_max (as the plugin; depthParam is 0 here, the plugin leaves it unset; a
    depth_max over 65.535 m keeps every value, where the plugin's cast would wrap).
    RVL: uint32 width, uint32 height, then the RVL words. A frame whose RVL stream the transport's
    decoder would refuse (`rvl_accepted`) goes as PNG; its format string says so, and the caller can
    tell from it (`compressed_depth_codec`).
    """
    pixels, params = _compressed_depth_pixels(depth, encoding, depth_max, depth_quantization)
    if codec == "rvl":
        stream = _rvl_stream(pixels)
        if not rvl_accepted(pixels.size, stream.size):
            codec, stream = "png", _png_stream(pixels, png_level, _UNFILTERED)
    else:
        stream = _png_stream(pixels, png_level)
    config = np.array([(_INV_DEPTH, params)], dtype=_CONFIG_HEADER)
    data = np.concatenate([config.view(np.uint8), stream])
    return types.CompressedImage(header=header, format=f"{encoding}; compressedDepth {codec}", data=_bytes(types, data))


def rvl_accepted(pixels: int, stream_bytes: int) -> bool:
    """Whether image_transport's decoder takes an RVL stream of `stream_bytes` (size prefix included) for
    `pixels` pixels. RVL compresses a real depth image at most about 4x, so codec.cpp (Jazzy, 32FC1)
    refuses a stream of more than 5 pixels a byte as "malformed RVL-encoded image"; but mostly invalid
    depth (a dark scene, a lens cap, max_depth in a large room) is long runs of zeros, which RVL packs
    far tighter. Its 16UC1 path has no such check; a stricter decoder may, so both encodings keep it."""
    return pixels <= RVL_MAX_PIXELS_PER_BYTE * stream_bytes


def compressed_depth_codec(msg: Any) -> str:
    """The codec a compressedDepth message holds ("png" or "rvl"), from its format string."""
    return str(msg.format).rpartition(" ")[2]


def _compressed_depth_pixels(
    depth: np.ndarray, encoding: str, depth_max: float, depth_quantization: float
) -> tuple[np.ndarray, tuple[np.float32, np.float32]]:
    """The 16-bit image the codec compresses, and the ConfigHeader's depthParam."""
    if encoding == "32FC1":
        a = np.float32(depth_quantization) * (np.float32(depth_quantization) + np.float32(1.0))
        b = np.float32(1.0) - a / np.float32(depth_max)
        with np.errstate(invalid="ignore", divide="ignore"):
            near = depth < np.float32(depth_max)  # False for NaN
            inverse = np.where(near, a / depth + b, np.float32(0.0))
        return np.minimum(inverse, np.float32(65535.0)).astype(np.uint16), (a, b)
    pixels = depth.copy()
    pixels[pixels > min(int(depth_max * 1000.0), 65535)] = 0
    return pixels, (np.float32(0.0), np.float32(0.0))


def _rvl_stream(pixels: np.ndarray) -> np.ndarray:
    height, width = pixels.shape
    return np.concatenate([np.array([width, height], "<u4").view(np.uint8), rvl_compress(pixels)])


def _png_stream(pixels: np.ndarray, png_level: int, options: tuple[int, ...] = ()) -> np.ndarray:
    ok, png = cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, png_level, *options])
    if not ok:
        msg = f"cannot encode a {pixels.shape[1]}x{pixels.shape[0]} depth image as PNG"
        raise ImageError(msg)
    return png.reshape(-1)
