"""Publishing a message that is already serialized, with the GIL released.

rclpy's `Publisher.publish()` holds the GIL from the conversion of the Python message to the end of
the DDS write: 7.6-12.5 ms for a 9.8 MB VGA points2 on a 2-core AMD EPYC (Zen 3), 14-19 ms in the node
with the matcher beside it. The matcher's thread needs the GIL between its OpenCV calls and the
executor needs it to take the next images, so the next frame waited for the previous frame's outputs.
The nodes therefore compute the disparity and an organized cloud straight into their CDR bytes
(`messages.in_serialized_bytes`, a `SerializedMessage`) and hand them to
`rcl_publish_serialized_message` through ctypes, which releases the GIL for the call: one copy fewer,
0.72-0.77x the time for that cloud, the other threads running meanwhile (docs/design/decisions.md).
rcl returns once Fast DDS has copied the bytes, so the buffer may be reused for the next frame, as
with `publish()`.

Where librcl cannot be loaded (another layout of the ROS install), rclpy publishes the same bytes
(`publish(bytes)`), holding the GIL as before.
"""

from __future__ import annotations

import ctypes
import functools
from typing import Any

from rclpy.lifecycle import LifecyclePublisher
from rclpy.publisher import Publisher

from stereo_depth.messages import SerializedMessage


class _Allocator(ctypes.Structure):  # rcutils_allocator_t: unused by a publish, zeroed
    _fields_ = [(name, ctypes.c_void_p) for name in ("allocate", "deallocate", "reallocate", "zero_allocate", "state")]


class _SerializedMessage(ctypes.Structure):  # rcl_serialized_message_t (rcutils_uint8_array_t)
    _fields_ = [
        ("buffer", ctypes.c_void_p),
        ("buffer_length", ctypes.c_size_t),
        ("buffer_capacity", ctypes.c_size_t),
        ("allocator", _Allocator),
    ]


class _ErrorString(ctypes.Structure):  # rcutils_error_string_t
    _fields_ = [("str", ctypes.c_char * 1024)]


class _Rcl:
    """The two rcl/rcutils functions, from the libraries rclpy has loaded (ctypes releases the GIL for
    every call it makes)."""

    def __init__(self) -> None:
        rcl, rcutils = ctypes.CDLL("librcl.so"), ctypes.CDLL("librcutils.so")
        self.publish = rcl.rcl_publish_serialized_message
        self.publish.argtypes = [ctypes.c_void_p, ctypes.POINTER(_SerializedMessage), ctypes.c_void_p]
        self.publish.restype = ctypes.c_int
        self.error = rcutils.rcutils_get_error_string
        self.error.restype = _ErrorString
        self.reset_error = rcutils.rcutils_reset_error


@functools.cache
def _rcl() -> _Rcl | None:
    try:
        return _Rcl()
    except (OSError, AttributeError):
        return None


def publish(publisher: Publisher, message: Any) -> None:
    """`publisher.publish(message)`; a `SerializedMessage` goes out as its bytes with the GIL released."""
    if not isinstance(message, SerializedMessage):
        publisher.publish(message)
        return
    rcl = _rcl()
    if rcl is None or (isinstance(publisher, LifecyclePublisher) and not publisher.is_activated):
        publisher.publish(message.buffer.tobytes())  # rclpy's own path: an inactive one skips it
        return
    size = message.buffer.nbytes
    raw = _SerializedMessage(message.buffer.ctypes.data, size, size, _Allocator())
    with publisher.handle:  # as rclpy's publish(): the publisher is not destroyed meanwhile
        ret = rcl.publish(publisher.handle.pointer, ctypes.byref(raw), None)
    if ret != 0:
        reason = rcl.error().str.decode(errors="replace")
        rcl.reset_error()
        raise RuntimeError(f"failed to publish on {publisher.topic_name} (rcl {ret}): {reason}")
