"""The node-only options (sync, QoS, threads, which outputs) and every parameter name stereo_depth knows.

ROS-free, so that `stereo-depth process` (no ROS needed) accepts a node's parameter file and tells a
misspelt key from a node-only one; ros/parameters.py declares the nodes' ROS parameters from here.
Each field carries its description and range in its metadata, as StereoParams' do.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Iterable
from dataclasses import dataclass, field

from stereo_depth.core.params import COMPAT_ALIASES, StereoParams, _spec
from stereo_depth.errors import ParameterError
from stereo_depth.frames import OutputOptions

RELIABILITY_CHOICES = ("auto", "reliable", "best_effort")
IMAGE_TRANSPORTS = ("raw", "compressed")
INTERPOLATIONS = {0: "nearest", 1: "linear", 2: "cubic", 3: "area", 4: "lanczos4"}


@dataclass(frozen=True)
class NodeOptions:
    """Node-only parameters; each node declares the subset it uses (see `*_OPTIONS`)."""

    queue_size: int = field(
        default=5, metadata=_spec("Messages kept per input while waiting for the rest of a set", 1, 100, 1)
    )
    approximate_sync: bool = field(
        default=False,
        metadata=_spec("Pair inputs whose stamps differ by up to approximate_sync_tolerance_seconds"),
    )
    approximate_sync_tolerance_seconds: float = field(
        default=0.0,
        metadata=_spec("Largest stamp difference inside one approximate set, s (0 = no limit)", 0.0, 10.0),
    )
    use_system_default_qos: bool = field(
        default=False,
        metadata=_spec("stereo_image_proc compatibility: true subscribes reliable when input_reliability is auto"),
    )
    input_reliability: str = field(
        default="auto",
        metadata=_spec("Subscription reliability: auto (follow the publishers, as rosbag2), reliable, best_effort"),
    )
    publish_rectified: bool = field(default=True, metadata=_spec("Publish left/image_rect(_color)"))
    publish_disparity: bool = field(default=True, metadata=_spec("Publish disparity (stereo_msgs/DisparityImage)"))
    publish_depth: bool = field(default=True, metadata=_spec("Publish depth (32FC1, metres, NaN invalid)"))
    publish_points: bool = field(default=True, metadata=_spec("Publish points2 (sensor_msgs/PointCloud2)"))
    publish_confidence: bool = field(
        default=True, metadata=_spec("Publish confidence (32FC1, 0..1) when the matcher gives one (census_sgm)")
    )
    calibration_check: bool = field(
        default=True,
        metadata=_spec("Check now and then that rectified rows still agree (report in diagnostics)"),
    )
    calibration_check_every_n_frames: int = field(
        default=30, metadata=_spec("Run the calibration check on one frame in this many", 1, 100000, 1)
    )
    max_waiting_frames: int = field(
        default=3,
        metadata=_spec(
            "Complete input sets kept while one is processed; one more drops the oldest (counted in "
            "diagnostics). 3: no frame lost to DDS delivering large images in bursts or to a busy machine's "
            "hiccups; 1: always the newest, lowest latency",
            1,
            100,
            1,
        ),
    )
    matching_threads: int = field(
        default=1,
        metadata=_spec(
            "Frames matched at once, outputs kept in input order. 2 raises the rate of a matcher that leaves "
            "cores idle (census_sgm: 1.3-1.4x on 2 cores, bench/parallel_matching.py) at the cost of latency",
            1,
            4,
            1,
        ),
    )
    image_transport: str = field(
        default="raw",
        metadata=_spec(
            "Image inputs, read at start-up (stereo_image_proc's meaning): raw (sensor_msgs/Image) or "
            "compressed (<image topic>/compressed, sensor_msgs/CompressedImage, JPEG or PNG)"
        ),
    )
    left_camera_info_url: str = field(
        default="",
        metadata=_spec(
            "Left camera_info YAML, read at start-up (file:///path/left.yaml, as camera_info_manager); "
            "when set it replaces the left/camera_info topic"
        ),
    )
    right_camera_info_url: str = field(
        default="",
        metadata=_spec("Right camera_info YAML, as left_camera_info_url; replaces the right/camera_info topic"),
    )
    interpolation: int = field(
        default=1,
        metadata=_spec("Rectification interpolation: 0 nearest, 1 linear, 2 cubic, 3 area, 4 lanczos4", 0, 4, 1),
    )

    def validate(self) -> NodeOptions:
        if self.input_reliability not in RELIABILITY_CHOICES:
            msg = f"input_reliability '{self.input_reliability}' must be one of {', '.join(RELIABILITY_CHOICES)}"
            raise ParameterError(msg)
        if self.image_transport not in IMAGE_TRANSPORTS:
            msg = f"image_transport '{self.image_transport}' must be one of {', '.join(IMAGE_TRANSPORTS)}"
            raise ParameterError(msg)
        return self

    @property
    def tolerance_ns(self) -> int:
        """The synchronizer's tolerance; 0 s means "no limit" as in stereo_image_proc (message_filters)."""
        if self.approximate_sync_tolerance_seconds <= 0:
            return 1 << 62
        return round(self.approximate_sync_tolerance_seconds * 1e9)

    @property
    def reliability(self) -> str:
        """The effective subscription policy: input_reliability, with use_system_default_qos honoured."""
        if self.input_reliability == "auto" and self.use_system_default_qos:
            return "reliable"
        return self.input_reliability


SYNC_OPTIONS = ("queue_size", "approximate_sync", "approximate_sync_tolerance_seconds")
INPUT_OPTIONS = (*SYNC_OPTIONS, "use_system_default_qos", "input_reliability", "max_waiting_frames", "max_image_pixels")
# what shapes points2 (stereo_node, point_cloud_node); stereo_node also declares depth_encoding
CLOUD_OPTIONS = (
    "use_color",
    "avoid_point_cloud_padding",
    "min_depth",
    "max_depth",
    "mask_image",
    "organized_cloud",
    "cloud_voxel_size",
    "points_max_rate",
)
# the temporal filter on the disparity (stereo_node)
TEMPORAL_OPTIONS = tuple(f.name for f in dataclasses.fields(OutputOptions) if f.name.startswith("temporal_"))
CAMERA_OPTIONS = ("image_transport", "left_camera_info_url", "right_camera_info_url")  # what the inputs are
STARTUP_OPTIONS = frozenset(CAMERA_OPTIONS)  # they choose the subscriptions: read-only once running


@dataclass(frozen=True)
class Settings:
    """One consistent set of values: what a frame is processed with (swapped as a whole)."""

    stereo: StereoParams | None
    options: NodeOptions
    output: OutputOptions = field(default_factory=OutputOptions)


# Parameters every rclpy node has, and the prefix of rclpy's per-topic QoS overrides.
ROS_BUILTINS = ("use_sim_time", "start_type_description_service")
ROS_BUILTIN_PREFIX = "qos_overrides."


def known_parameters() -> set[str]:
    """Every parameter name of any stereo_depth node (a node ignores the ones it does not declare)."""
    classes = (StereoParams, OutputOptions, NodeOptions)
    return {"profile", *COMPAT_ALIASES, *(f.name for cls in classes for f in dataclasses.fields(cls))}


def unknown_parameters_line(names: Iterable[str]) -> str | None:
    """One line naming the given parameters that no stereo_depth node knows, each with the closest
    known name; None when all are known."""
    known = known_parameters()
    unknown = sorted(
        n for n in names if n not in known and n not in ROS_BUILTINS and not n.startswith(ROS_BUILTIN_PREFIX)
    )
    if not unknown:
        return None
    return "unknown parameters, ignored: " + "; ".join(_with_hint(name, known) for name in unknown)


def _with_hint(name: str, known: Iterable[str]) -> str:
    close = difflib.get_close_matches(name, sorted(known), n=1)
    return f"'{name}' (did you mean '{close[0]}'?)" if close else f"'{name}'"
