"""Calibrated stereo frames into a bag (rosbag2, or ROS 1 with --storage rosbag1) as a camera driver would publish them.

Each frame becomes four messages with one header stamp: left/right `sensor_msgs/Image` (mono8, mono16
or bgr8, as read) and left/right `sensor_msgs/CameraInfo`. Recordings as they come from robots and
datasets can be made too: images as image_transport's `sensor_msgs/CompressedImage` (JPEG or PNG, on
`<image topic>/compressed`), and no camera_info at all (EuRoC's bags: calibration in files).
Ground truth, when the frames have it, is written beside the bag (`ground_truth.py`) keyed by the same
stamps, so accuracy can be checked on what comes out of `process` or a live node.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from stereo_depth.bag.ground_truth import GroundTruthWriter
from stereo_depth.bag.reader import ROLES
from stereo_depth.bag.sources import SourceFrame
from stereo_depth.bag.types import rosbags_types
from stereo_depth.bag.writer import BagWriter
from stereo_depth.errors import BagError
from stereo_depth.messages import (
    COMPRESSED_FORMATS,
    array_to_compressed,
    array_to_image,
    camera_info_to_msg,
    make_header,
)

DEFAULT_RATE_HZ = 10.0
DEFAULT_NAMES = ("left/image_raw", "left/camera_info", "right/image_raw", "right/camera_info")


@dataclass(frozen=True)
class StreamLayout:
    """Topic names (in ROLES order), frame ids and timing of the stream being written."""

    namespace: str = "/stereo"
    names: tuple[str, ...] = DEFAULT_NAMES
    left_frame_id: str = "left_camera_optical_frame"
    right_frame_id: str = "right_camera_optical_frame"
    rate_hz: float | None = None  # None: keep the stamps in the file names (else DEFAULT_RATE_HZ)
    start_ns: int = 1_700_000_000_000_000_000
    overrides: dict[str, str] = field(default_factory=dict)
    compress_images: str | None = None  # "jpeg" or "png": CompressedImage on <image topic>/compressed
    camera_info: bool = True  # False: images only, as EuRoC's bags (calibration from files)

    def topics(self) -> tuple[str, ...]:
        """Full topic names; a relative name (no leading /) goes under the namespace."""
        namespace = "/" + self.namespace.strip("/") if self.namespace.strip("/") else ""
        named = [self.overrides.get(role, name) for role, name in zip(ROLES, self.names, strict=True)]
        full = [n if n.startswith("/") else f"{namespace}/{n}" for n in named]
        if self.compress_images is not None:
            full[0], full[2] = f"{full[0]}/compressed", f"{full[2]}/compressed"
        return tuple(full)

    def written(self) -> tuple[str, ...]:
        """The topics that get messages."""
        left_image, left_info, right_image, right_info = self.topics()
        return (left_image, left_info, right_image, right_info) if self.camera_info else (left_image, right_image)


def parse_topic_overrides(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        role, sep, name = item.partition("=")
        if not sep or role not in ROLES or not name:
            msg = f"--topic expects ROLE=NAME with ROLE one of {', '.join(ROLES)}; got '{item}'"
            raise BagError(msg)
        out[role] = name
    return out


def stamped(frames: Iterable[SourceFrame], layout: StreamLayout) -> Iterator[tuple[int, SourceFrame]]:
    """File-name stamps when the first frame has one and no rate was asked for, else a steady rate."""
    period_ns = round(1e9 / (layout.rate_hz or DEFAULT_RATE_HZ))
    use_names: bool | None = None
    previous = -1
    for index, frame in enumerate(frames):
        if use_names is None:
            use_names = layout.rate_hz is None and frame.stamp_ns is not None
        if use_names and frame.stamp_ns is None:
            msg = f"{frame.name}: no nanosecond stamp in the file name, unlike the first frame; pass --rate"
            raise BagError(msg)
        stamp = frame.stamp_ns if use_names and frame.stamp_ns is not None else layout.start_ns + index * period_ns
        if stamp <= previous:
            msg = f"{frame.name}: stamp {stamp} ns does not increase; pass --rate to restamp the frames"
            raise BagError(msg)
        previous = stamp
        yield stamp, frame


def write_stream(
    frames: Iterable[SourceFrame],
    writer: BagWriter,
    layout: StreamLayout,
    ground_truth: GroundTruthWriter | None = None,
) -> int:
    """Write every frame as four messages; returns the number of frames."""
    types = rosbags_types()
    left_image, left_info, right_image, right_info = layout.topics()
    codec = layout.compress_images
    if codec is not None and codec not in COMPRESSED_FORMATS:
        msg = f"--compress-images {codec}: choose one of {', '.join(COMPRESSED_FORMATS)}"
        raise BagError(msg)

    def image(header: Any, pixels: Any) -> Any:
        if codec is None:
            return array_to_image(types, header, pixels)
        return array_to_compressed(types, header, pixels, codec)

    count = 0
    for stamp, frame in stamped(frames, layout):
        left_header = make_header(types, stamp, layout.left_frame_id)
        right_header = make_header(types, stamp, layout.right_frame_id)
        writer.write(left_image, image(left_header, frame.left), stamp)
        if layout.camera_info:
            writer.write(left_info, camera_info_to_msg(types, left_header, frame.left_info), stamp)
        writer.write(right_image, image(right_header, frame.right), stamp)
        if layout.camera_info:
            writer.write(right_info, camera_info_to_msg(types, right_header, frame.right_info), stamp)
        if ground_truth is not None and frame.gt is not None:
            ground_truth.add(stamp, frame.name, frame.gt, frame.mask)
        count += 1
    if count == 0:
        msg = "no frames to write"
        raise BagError(msg)
    return count
