"""Message <-> array conversion by field names, for rclpy messages and rosbags messages alike.

This module imports neither ROS nor rosbags: callers hand in a `MessageTypes` (the classes of their
flavour) and get messages of that flavour back. Every image encoding, row padding, byte order and
point-cloud layout detail lives here and nowhere else.

Reading never copies when it does not have to (np.frombuffer over the message buffer); writing copies
each buffer once (rclpy's setter takes an array.array without looking at every element), and a flavour
with `serialize` (the live nodes') gets the disparity and organized clouds computed straight into their
serialized bytes (`in_serialized_bytes`).
"""

from __future__ import annotations

import array
import dataclasses
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import cv2
import numpy as np

from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.core.geometry import Rays, point_planes
from stereo_depth.core.rvl import rvl_compress
from stereo_depth.errors import ImageError

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


DEFAULT_MAX_PIXELS = 4096 * 4096


@dataclass(frozen=True)
class MessageTypes:
    """The message classes of one flavour (rclpy's generated classes or a rosbags typestore's)."""

    Header: Any
    Time: Any
    Image: Any
    CompressedImage: Any
    CameraInfo: Any
    RegionOfInterest: Any
    DisparityImage: Any
    PointCloud2: Any
    PointField: Any
    # rclpy's serialize_message: a disparity and an organized cloud are then built in their CDR bytes
    serialize: Callable[[Any], bytes] | None = None

    @property
    def is_rosbags(self) -> bool:
        return dataclasses.is_dataclass(self.Image)


class SerializedMessage(NamedTuple):
    """A message as the bytes rclpy's `serialize_message` gives (CDR), for stereo_depth.ros.serialized_publish
    to publish without converting a Python message first."""

    msg_type: Any
    buffer: np.ndarray  # uint8, the whole serialized message


# ---------------------------------------------------------------- headers


def stamp_to_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def make_header(types: MessageTypes, stamp_ns: int, frame_id: str) -> Any:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return types.Header(stamp=types.Time(sec=sec, nanosec=nanosec), frame_id=frame_id)


def _bytes(types: MessageTypes, data: np.ndarray) -> Any:
    flat = np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    if types.is_rosbags:
        return flat
    out = array.array("B")
    out.frombytes(memoryview(flat))
    return out


def _with_data(types: MessageTypes, cls: Any, data: Any, **fields: Any) -> Any:
    """A message whose `data` is the buffer given, not a copy; rosbags' dataclasses take it as is.

    rclpy's constructor copies `data` into a new array.array (3.6 ms for a VGA cloud), and so does its
    setter unless the message checks its fields: only then does it keep an array.array as it is.
    """
    if types.is_rosbags:
        return cls(**fields, data=data)
    msg = cls(check_fields=True, **fields)
    msg.data = data
    return msg


def _floats(types: MessageTypes, values: np.ndarray) -> Any:
    values = np.asarray(values, dtype=np.float64).ravel()
    return values if types.is_rosbags else array.array("d", values.tobytes())


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
    if height * width > max_pixels:
        msg_text = (
            f"image is {width}x{height}, more than the limit of {max_pixels} pixels; "
            "raise the max_image_pixels parameter if images this large are intended"
        )
        raise ImageError(msg_text)
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
    if height * width > max_pixels:
        msg_text = (
            f"image is {width}x{height}, more than the limit of {max_pixels} pixels; "
            "raise the max_image_pixels parameter if images this large are intended"
        )
        raise ImageError(msg_text)
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
# (3.2-3.6 kB at 752x480), and libpng's adaptive filter choice costs 8-15 ms of such a frame, unfiltered 1-2
_UNFILTERED = (cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE)
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


# ---------------------------------------------------------------- camera info


def camera_info_from_msg(msg: Any) -> CameraInfo:
    return CameraInfo.from_values(
        msg.width, msg.height, msg.k, msg.d, msg.r, msg.p, msg.distortion_model, msg.header.frame_id
    )


def same_calibration(a: Any, b: Any) -> bool:
    """Whether two CameraInfo messages (rclpy or rosbags) describe one calibration, stamps aside: the
    synchronizer lets the last camera_info stand in for a lost one only while this holds."""
    scalars = ("width", "height", "distortion_model", "binning_x", "binning_y")
    if any(getattr(a, name) != getattr(b, name) for name in scalars) or a.header.frame_id != b.header.frame_id:
        return False
    return all(np.array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name))) for name in "dkrp")


def camera_info_to_msg(types: MessageTypes, header: Any, info: CameraInfo) -> Any:
    roi = types.RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return types.CameraInfo(
        header=header,
        height=info.height,
        width=info.width,
        distortion_model=info.distortion_model,
        d=_floats(types, info.d),
        k=np.asarray(info.k, np.float64).ravel(),
        r=np.asarray(info.r, np.float64).ravel(),
        p=np.asarray(info.p, np.float64).ravel(),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


# ---------------------------------------------------------------- disparity


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


# ---------------------------------------------------------------- point clouds

FLOAT32 = 7  # sensor_msgs/PointField FLOAT32


def cloud_layout(with_color: bool, avoid_padding: bool) -> tuple[list[tuple[str, int]], int]:
    """Field offsets and point_step as stereo_image_proc lays them out (PCL-style rgb)."""
    if with_color:
        return ([("x", 0), ("y", 4), ("z", 8), ("rgb", 12 if avoid_padding else 16)], 16 if avoid_padding else 32)
    return ([("x", 0), ("y", 4), ("z", 8)], 12 if avoid_padding else 16)


def pack_rgb(bgr: np.ndarray) -> np.ndarray:
    """PCL's rgb: 0x00RRGGBB as uint32, read as float32 by consumers."""
    b, g, r = (bgr[:, :, i].astype(np.uint32) for i in range(3))
    return (r << 16) | (g << 8) | b


class MessageBuffer:
    """The data bytes of a publisher's last message, handed to its next one of the same size and layout.

    A VGA cloud is 10 MB, a VGA disparity 1.2 MB: allocating them per frame costs more than filling
    them, and building the data elsewhere costs a copy into the message. rclpy's `publish()` serializes
    before it returns (rcl copies a SerializedMessage's bytes before it returns, and the bag writer
    serializes too), so a node may reuse the buffer for its next frame; keep one per publisher and
    never reuse it while a message built on it is still to be published.
    Every byte, padding included, is written for each message, so a reused buffer holds what a fresh
    one would.
    """

    def __init__(self) -> None:
        self._key: tuple[object, ...] | None = None
        self._data: Any = None

    def get(self, types: MessageTypes, key: tuple[object, ...], size: int) -> Any:
        """`size` bytes for a message's data: an array.array for rclpy's, a numpy array for rosbags'."""
        if types.is_rosbags:
            return self.numpy(key, size)
        if self._key != key:
            self._data = array.array("B", bytes(size))
            self._key = key
        return self._data

    def numpy(self, key: tuple[object, ...], size: int) -> np.ndarray:
        """`size` bytes as a uint8 numpy array."""
        if self._key != ("numpy", key):
            self._data = np.zeros(size, np.uint8)
            self._key = ("numpy", key)
        data: np.ndarray = self._data
        return data


# bytes that stand for a message's data while it is serialized: where they land, the data goes
DATA_MARK = bytes.fromhex("a55ac33c96690ff0")


def in_serialized_bytes(
    types: MessageTypes, build: Callable[[Any], Any], size: int, buffer: MessageBuffer
) -> tuple[SerializedMessage, np.ndarray] | None:
    """The message `build(data)` gives, as its serialized bytes in `buffer` with `size` data bytes
    left to fill (the second item, a view of them). The message is serialized once with a mark as its
    data, 8 to 15 bytes long and as long as `size` modulo 8, so what follows the data is aligned as
    after the mark; the real data replaces the mark, its length (uint32) the mark's. None (build the
    message instead) without `types.serialize`, or if the mark is not found exactly once."""
    if types.serialize is None:
        return None
    mark = (DATA_MARK * 2)[: len(DATA_MARK) + size % len(DATA_MARK)]
    message = build(_bytes(types, np.frombuffer(mark, np.uint8)))
    marked = types.serialize(message)
    at = marked.find(mark)
    if at < 8 or marked.find(mark, at + 1) != -1:
        return None
    prefix, tail = marked[: at - 4], marked[at + len(mark) :]
    order = "<" if marked[1] == 1 else ">"  # the encapsulation: CDR little endian (1) or big endian (0)
    out = buffer.numpy((len(prefix), len(tail), size), len(prefix) + 4 + size + len(tail))
    out[: len(prefix)] = np.frombuffer(prefix, np.uint8)
    out[len(prefix) : at] = np.array([size], order + "u4").view(np.uint8)
    out[at + size :] = np.frombuffer(tail, np.uint8)
    return SerializedMessage(type(message), out), out[at : at + size]


def depth_to_cloud(
    types: MessageTypes,
    header: Any,
    depth: np.ndarray,
    rays: Rays,
    color: np.ndarray | None = None,
    avoid_padding: bool = False,
    buffer: MessageBuffer | None = None,
    *,
    organized: bool = True,
    voxel_size: float = 0.0,
) -> Any:
    """PointCloud2 of a depth image: the one cloud builder.

    `organized`: height x width points, NaN for invalid ones, is_dense false (stereo_image_proc's
    layout), x, y, z computed straight into the message's buffer. Otherwise the valid points only
    (REP 117's dense cloud: height 1, is_dense true), thinned to one point per `voxel_size` voxel when
    that is > 0 (the members' centroid, the colour of one of them).
    `color` is BGR or grey (uint8); `buffer` lends the bytes of the previous organized cloud (see
    MessageBuffer).
    """
    fields, point_step = cloud_layout(color is not None, avoid_padding)
    height, width = depth.shape
    buffer = buffer or MessageBuffer()

    def cloud(data: Any, height: int, width: int) -> Any:
        return _with_data(
            types,
            types.PointCloud2,
            data,
            header=header,
            height=height,
            width=width,
            fields=[types.PointField(name=n, offset=o, datatype=FLOAT32, count=1) for n, o in fields],
            is_bigendian=sys.byteorder == "big",
            point_step=point_step,
            row_step=point_step * width,
            is_dense=not organized,
        )

    size = height * width * point_step
    serialized = (
        in_serialized_bytes(types, lambda data: cloud(data, height, width), size, buffer) if organized else None
    )
    if serialized is not None:  # the points written into the serialized message (rclpy)
        _fill_records(serialized[1].reshape(height, width, point_step), fields, depth, rays, color)
        return serialized[0]
    data = buffer.get(types, (height, width, tuple(fields), point_step), size)
    records = np.frombuffer(data, dtype=np.uint8).reshape(height, width, point_step)
    _fill_records(records, fields, depth, rays, color)
    if not organized:  # the valid points, copied out of the organized records (faster than gathering)
        kept = np.compress(np.isfinite(depth).ravel(), records.reshape(-1, point_step), axis=0)
        if voxel_size > 0:
            kept = _voxel_records(kept, fields, voxel_size)
        height, width = 1, len(kept)
        data = _bytes(types, kept)
    return cloud(data, height, width)


def _fill_records(
    records: np.ndarray, fields: list[tuple[str, int]], depth: np.ndarray, rays: Rays, color: np.ndarray | None
) -> None:
    """Every point's x, y, z and rgb, padding zero, written into the (H, W, point_step) records in one
    pass over them (cv2.merge): 1.5x sooner than a strided write per field."""
    height, width, point_step = records.shape
    words = dict(enumerate(point_planes(depth, rays)))  # float32 word of a record -> its plane
    if color is not None:
        words[fields[3][1] // 4] = _packed(color).view(np.float32)
    count = point_step // 4
    if len(words) < count:  # padding words: zero
        zero = np.zeros((height, width), np.float32)
        words.update((i, zero) for i in range(count) if i not in words)
    cv2.merge([words[i] for i in range(count)], dst=records.view(np.float32).reshape(height, width, count))


def _packed(color: np.ndarray) -> np.ndarray:
    """(H, W) PCL rgb of a BGR or grey (r = g = b) image."""
    if color.ndim == 2:
        grey: np.ndarray = np.multiply(color, np.uint32(0x010101), dtype=np.uint32)
        return grey
    return pack_rgb(color)


def _rgb_view(records: np.ndarray, fields: list[tuple[str, int]]) -> np.ndarray:
    """The rgb field of (..., point_step) uint8 records as uint32, (...)."""
    offset = fields[3][1]
    view: np.ndarray = records[..., offset : offset + 4].view(np.uint32)[..., 0]
    return view


def _voxel_records(records: np.ndarray, fields: list[tuple[str, int]], size: float) -> np.ndarray:
    """(N, point_step) records thinned to one per voxel (`voxel_thinned`), padding zero."""
    rgb = _rgb_view(records, fields) if len(fields) > 3 else None
    xyz, rgb = voxel_thinned(records.view(np.float32)[:, 0:3], rgb, size)
    out = np.zeros((len(xyz), records.shape[1]), np.uint8)
    out.view(np.float32)[:, 0:3] = xyz
    if rgb is not None:
        _rgb_view(out, fields)[...] = rgb
    return out


def voxel_thinned(xyz: np.ndarray, rgb: np.ndarray | None, size: float) -> tuple[np.ndarray, np.ndarray | None]:
    """One point per occupied cube of edge `size` (metres): the centroid of its points, and the colour
    of one of them (a mean of packed colours would be no colour at all). Sorting by cube is the cost."""
    if len(xyz) == 0:
        return xyz, rgb
    scale = np.float32(1.0 / size)
    ids = np.zeros(len(xyz), np.int64)
    for axis in range(3):  # column by column: reductions over an (N, 3) array's axis 0 are slow
        cell = np.floor(xyz[:, axis] * scale).astype(np.int64)
        low = cell.min()
        ids *= cell.max() - low + 1
        ids += cell - low
    order = np.argsort(ids)
    ids = ids[order]
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    counts = np.diff(np.r_[starts, len(ids)])
    centroids = np.empty((len(starts), 3), np.float32)
    for axis in range(3):
        centroids[:, axis] = np.add.reduceat(xyz[order, axis], starts, dtype=np.float64) / counts
    return centroids, rgb[order[starts]] if rgb is not None else None


def cloud_to_arrays(msg: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, 3) xyz float32 and (H, W) uint32 rgb (or None), read by field name from any layout."""
    offsets = {f.name: int(f.offset) for f in msg.fields}
    for name in ("x", "y", "z"):
        if name not in offsets:
            msg_text = f"point cloud has no '{name}' field (fields: {sorted(offsets)})"
            raise ImageError(msg_text)
    endian = ">" if msg.is_bigendian else "<"
    names = ["x", "y", "z"] + (["rgb"] if "rgb" in offsets else [])
    dtype = np.dtype(
        {
            "names": names,
            "formats": [endian + ("u4" if n == "rgb" else "f4") for n in names],
            "offsets": [offsets[n] for n in names],
            "itemsize": int(msg.point_step),
        }
    )
    records = np.frombuffer(msg.data, dtype=dtype).reshape(int(msg.height), int(msg.width))
    xyz = np.stack([records["x"], records["y"], records["z"]], axis=-1).astype(np.float32)
    rgb = records["rgb"].astype(np.uint32) if "rgb" in offsets else None
    return xyz, rgb
