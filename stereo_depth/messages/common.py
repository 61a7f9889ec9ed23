"""What every converter shares: the message classes of a flavour, headers, and message buffers.

Reading never copies when it does not have to (np.frombuffer over the message buffer); writing copies
each buffer once (rclpy's setter takes an array.array without looking at every element), and a flavour
with `serialize` (the live nodes') gets the disparity and organized clouds computed straight into their
serialized bytes (`in_serialized_bytes`).
"""

from __future__ import annotations

import array
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from stereo_depth.errors import ImageError

DEFAULT_MAX_PIXELS = 4096 * 4096


def check_pixel_count(width: int, height: int, max_pixels: int) -> None:
    """The one pixel limit of every decoded image (max_image_pixels): refused before memory is spent on it."""
    if height * width > max_pixels:
        msg_text = (
            f"image is {width}x{height}, more than the limit of {max_pixels} pixels; "
            "raise the max_image_pixels parameter if images this large are intended"
        )
        raise ImageError(msg_text)


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
