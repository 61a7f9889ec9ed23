"""Every option of stereo_depth, each stated once: name, type, default, range or choices, doc.

ROS-free. Three tables, one dataclass each, one field per option (`option(default, doc, lo, hi, step)`;
a list of numbers adds `length=N`, a pose `[x, y, z, qx, qy, qz, qw]` is `pose_option(doc)`):

- `StereoParams` (core/params.py, with the profiles): what a frame is computed with;
- `OutputOptions`: how outputs are built, live and offline alike (node parameters, `process --set`);
- `NodeOptions`: inputs, sync, QoS, which outputs: a live node's (`process` reads the sync ones).

The nodes' ROS parameters (ros/parameters.py), config/stereo_depth.yaml and docs/parameters.md
(options_docs.py), `process --set/--params` and the sync flags of `process` and `demo` are read from
these fields. Adding an option is adding a field to one of them (and regenerating the two documents).
Descriptions say what an option does; what it costs or gains, measured, belongs in docs/tuning.md.
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import yaml

from stereo_depth.core.option_fields import check_ranges, coerced, option, pose_option, spec_of
from stereo_depth.core.params import COMPAT_ALIASES, StereoParams
from stereo_depth.core.pose import Pose
from stereo_depth.errors import ParameterError
from stereo_depth.mask_image import read_mask
from stereo_depth.messages import COMPRESSED_DEPTH_FORMATS, DEFAULT_MAX_PIXELS


@dataclass(frozen=True)
class OutputOptions:
    """How outputs are built, live and offline alike (ROS parameters of the nodes, `process --set`)."""

    use_color: bool = option(True, "Add PCL-style packed rgb to points2")
    avoid_point_cloud_padding: bool = option(
        False, "Pack points2 tightly (16-byte points) instead of stereo_image_proc's 32"
    )
    max_image_pixels: int = option(
        DEFAULT_MAX_PIXELS, "Refuse input images with more pixels than this (protects memory)", 1, 1 << 28, 1
    )
    depth_encoding: str = option(
        "32FC1",
        "depth image encoding: 32FC1 (metres, NaN invalid) or 16UC1 (millimetres, 0 invalid, REP 118; "
        "beyond 65.535 m invalid)",
        choices=("32FC1", "16UC1"),
    )
    min_depth: float = option(0.0, "Nearer points are invalid in depth and points2, metres (0 = no limit)", 0.0, 1e4)
    max_depth: float = option(0.0, "Farther points are invalid in depth and points2, metres (0 = no limit)", 0.0, 1e4)
    mask_image: str = option(
        "",
        "Path of an image the size of the raw left image: where it is zero (robot body, bumper, lens "
        "hood) nothing is output in depth or points2. Empty: no mask",
    )
    organized_cloud: bool = option(
        True,
        "points2 organized like the image (stereo_image_proc's layout, NaN invalid), or false: the valid "
        "points only (height 1, is_dense, no NaN)",
    )
    cloud_voxel_size: float = option(
        0.0, "With organized_cloud false: one point per voxel of this edge, metres (0 = off)", 0.0, 100.0
    )
    points_decimation: int = option(
        1,
        "points2 and points2_clearing from every Nth row and column of the depth image (1, 2 or 4): 1/N^2 the "
        "points, each its own pixel's ray and depth (no averaging); depth stays at its full size. Counted in "
        "the depth image's pixels (after downsample_output: processed), taken before organized_cloud: false "
        "and cloud_voxel_size thin what is left",
        choices=(1, 2, 4),
    )
    points_max_rate: float = option(
        0.0,
        "Publish points2 (and points2_clearing) at most this often, Hz, judged by stamps (0 = every frame)",
        0.0,
        1000.0,
    )
    baseline: float = option(
        0.0,
        "Stereo baseline, metres, for drivers whose right camera_info has P[0,3] zero or of the wrong sign: "
        "it replaces P[0,3] by -fx * baseline (0 = use the camera_info)",
        0.0,
        100.0,
    )
    swap_left_right: bool = option(
        False, "The driver's left topics carry the right camera and the right ones the left: swap them"
    )
    clearing_max_depth: float = option(
        10.0,
        "points2_clearing: each point lies along its pixel's ray at its depth, but no farther than this, "
        "metres (a costmap clears free space out to it)",
        0.1,
        1e4,
    )
    # too near for the disparity range
    near_points: str = option(
        "invalid",
        "Pixels too near for disparity_range (near_detection) in points2: invalid (no point) or range_limit "
        "(one point each along its ray at the nearest depth the range can see: a costmap marks an obstacle "
        "at least that near); mask_image and min_depth still apply, depth and points2_clearing never have them",
        choices=("invalid", "range_limit"),
    )
    compressed_depth_format: str = option(
        "png",
        "depth/compressedDepth codec: png or rvl (image_transport's compressedDepth format); rvl sends a "
        "frame as PNG where its RVL stream is too small for image_transport's decoder to accept (mostly "
        "invalid depth)",
        choices=COMPRESSED_DEPTH_FORMATS,
    )
    compressed_depth_max_depth: float = option(
        10.0, "depth/compressedDepth: farther depth is invalid in it, metres (the transport's depth_max)", 1.0, 100.0
    )
    compressed_depth_quantization: float = option(
        100.0,
        "depth/compressedDepth of 32FC1: depth at which the 16-bit inverse depth steps by 1 m, metres "
        "(the transport's depth_quantization)",
        1.0,
        150.0,
    )
    compressed_depth_png_level: int = option(
        3, "depth/compressedDepth PNG compression level (the transport's png_level)", 0, 9, 1
    )
    # depth registered to a colour camera (frames/registered.py)
    rgb_in_left: Pose = pose_option(
        "The colour camera's optical frame in the left camera's optical frame as calibrated (the raw left "
        "camera_info's frame, as URDF and Kalibr give it), [x, y, z, qx, qy, qz, qw]: set, the node reads "
        "rgb/image_raw + rgb/camera_info and publishes depth_registered/image_rect, depth_registered/camera_info, "
        "rgb/image_rect_color and depth_registered/points. Seven zeros: off (read at start-up)"
    )
    rgb_sync_tolerance_seconds: float = option(
        0.016,
        "A colour image pairs with the stereo set nearest in stamp within this, s (about half a colour frame "
        "period); a stereo set with none gives no registered output",
        0.0,
        1.0,
    )
    # the temporal filter's history moved by odometry (core/odometry.py, frames/odometry.py)
    left_in_base: Pose = pose_option(
        "The left camera's optical frame as calibrated (the raw left camera_info's frame, as URDF gives it) in "
        "the frame the odometry moves (nav_msgs/Odometry's child_frame_id, e.g. base_link), [x, y, z, qx, qy, "
        "qz, qw]: set, the node reads odom (nav_msgs/Odometry) and temporal_filter moves its history with the "
        "camera. Seven zeros: off (read at start-up)"
    )
    odom_wait_seconds: float = option(
        0.1,
        "With left_in_base set: how long a frame waits for the odometry message at or after its stamp (then it "
        "is filtered without odometry), and the longest gap between odometry messages that still counts as "
        "flowing odometry (a longer one makes the temporal filter forget its history), s",
        0.0,
        2.0,
    )

    def validate(self) -> OutputOptions:
        check_ranges(self)
        checks = [
            (
                not (self.min_depth > 0 and self.max_depth > 0) or self.max_depth > self.min_depth,
                f"max_depth ({self.max_depth}) must be greater than min_depth ({self.min_depth})",
            ),
            (
                self.cloud_voxel_size == 0 or not self.organized_cloud,
                "cloud_voxel_size thins the unorganized cloud: set organized_cloud to false as well",
            ),
        ]
        for ok, reason in checks:
            if not ok:
                raise ParameterError(reason)
        if self.mask_image:
            read_mask(self.mask_image)  # refused now, not frame after frame
        return self


@dataclass(frozen=True)
class NodeOptions:
    """Node-only parameters; each node declares the subset it uses (see `*_OPTIONS`)."""

    queue_size: int = option(5, "Messages kept per input while waiting for the rest of a set", 1, 100, 1)
    approximate_sync: bool = option(
        False, "Pair inputs whose stamps differ by up to approximate_sync_tolerance_seconds"
    )
    approximate_sync_tolerance_seconds: float = option(
        0.0, "Largest stamp difference inside one approximate set, s (0 = no limit)", 0.0, 10.0
    )
    use_system_default_qos: bool = option(
        False, "stereo_image_proc compatibility: true subscribes reliable when input_reliability is auto"
    )
    input_reliability: str = option(
        "auto",
        "Subscription reliability: auto (follow the publishers, as rosbag2), reliable, best_effort",
        choices=("auto", "reliable", "best_effort"),
    )
    publish_rectified: bool = option(
        True,
        "Publish left/image_rect(_color) and right/image_rect(_color) (stereo odometry's inputs; built only "
        "while subscribed): the camera's own bit depth, a 16-bit camera unscaled",
    )
    publish_disparity: bool = option(True, "Publish disparity (stereo_msgs/DisparityImage)")
    publish_depth: bool = option(True, "Publish depth (32FC1, metres, NaN invalid)")
    publish_points: bool = option(True, "Publish points2 (sensor_msgs/PointCloud2)")
    publish_points_clearing: bool = option(
        False,
        "Publish points2_clearing: a point along the ray of each pixel matched beyond max_depth or at the "
        "smallest disparity, for costmaps to clear free space with (stereo_node)",
    )
    publish_confidence: bool = option(
        True, "Publish confidence (32FC1, 0..1: how likely each disparity is right; 0 where invalid)"
    )
    calibration_check: bool = option(True, "Check now and then that rectified rows still agree (report in diagnostics)")
    calibration_check_every_n_frames: int = option(
        30, "Run the calibration check on one frame in this many", 1, 100000, 1
    )
    max_waiting_frames: int = option(
        3,
        "Most complete input sets kept while one is processed; one more drops the oldest (counted in "
        "diagnostics). Fewer wait as the node falls behind, only the newest under sustained overload. 3: "
        "no frame lost to DDS delivering large images in bursts or to a busy machine's hiccups; 1: always "
        "the newest, lowest latency",
        1,
        100,
        1,
    )
    max_latency_ms: float = option(
        0.0,
        "Budget from an input's receipt to its outputs, ms: a set that would be out later is dropped "
        "before work is spent on it (counted in diagnostics). 0: no budget",
        0.0,
        10000.0,
    )
    cpu_threads: int = option(
        0,
        "OpenCV and numba threads for one frame's matching; 0: this process's cores, shared among the "
        "frames matched at once (matching_threads)",
        0,
        256,
        1,
    )
    matching_threads: int = option(
        1,
        "Frames matched at once, outputs kept in input order. 2 raises the rate of a matcher that leaves "
        "cores idle (census_sgm) at the cost of latency",
        1,
        4,
        1,
    )
    executor: str = option(
        "standard",
        "rclpy executor, read at start-up: standard (SingleThreadedExecutor) or events (rclpy's experimental "
        "C++ EventsExecutor: less latency and CPU a frame; diagnostics then lack the inputs' time in DDS, "
        "which it does not pass on)",
        choices=("standard", "events"),
    )
    image_transport: str = option(
        "raw",
        "Image inputs, read at start-up (stereo_image_proc's meaning): raw (sensor_msgs/Image) or "
        "compressed (<image topic>/compressed, sensor_msgs/CompressedImage, JPEG or PNG)",
        choices=("raw", "compressed"),
    )
    left_camera_info_url: str = option(
        "",
        "Left camera_info YAML, read at start-up (file:///path/left.yaml, as camera_info_manager); "
        "when set it replaces the left/camera_info topic",
    )
    right_camera_info_url: str = option(
        "", "Right camera_info YAML, as left_camera_info_url; replaces the right/camera_info topic"
    )
    interpolation: int = option(
        1, "Rectification interpolation: 0 nearest, 1 linear, 2 cubic, 3 area, 4 lanczos4", 0, 4, 1
    )
    # depth registered to a colour camera
    rgb_image_transport: str = option(
        "raw",
        "The colour input, read at start-up: raw (rgb/image_raw) or compressed (rgb/image_raw/compressed), "
        "apart from the stereo pair's image_transport",
        choices=("raw", "compressed"),
    )

    def validate(self) -> NodeOptions:
        return check_ranges(self)

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


OPTION_CLASSES = (StereoParams, OutputOptions, NodeOptions)

# Which options each node declares, by role.
SYNC_OPTIONS = ("queue_size", "approximate_sync", "approximate_sync_tolerance_seconds")
INPUT_OPTIONS = (
    *SYNC_OPTIONS,
    "use_system_default_qos",
    "input_reliability",
    "max_waiting_frames",
    "max_latency_ms",
    "max_image_pixels",
    "executor",
)
# what shapes points2 (stereo_node, point_cloud_node); stereo_node also declares depth_encoding
CLOUD_OPTIONS = (
    "use_color",
    "avoid_point_cloud_padding",
    "min_depth",
    "max_depth",
    "mask_image",
    "organized_cloud",
    "cloud_voxel_size",
    "points_decimation",
    "points_max_rate",
)
# what the driver got wrong, stated by the user (point_cloud_node, which has no image pair, takes baseline only)
DRIVER_FIX_OPTIONS = ("baseline", "swap_left_right")
CAMERA_OPTIONS = ("image_transport", "left_camera_info_url", "right_camera_info_url")  # what the inputs are
# depth registered to a colour camera: its pose switches the colour inputs on (stereo_node)
REGISTRATION_OPTIONS = ("rgb_in_left", "rgb_sync_tolerance_seconds", "rgb_image_transport")
# the temporal filter's odometry: its pose switches the odom input on (the nodes with temporal_filter)
ODOMETRY_OPTIONS = ("left_in_base", "odom_wait_seconds")
# they choose the subscriptions: read-only once running
STARTUP_OPTIONS = frozenset((*CAMERA_OPTIONS, "executor", "rgb_in_left", "rgb_image_transport", "left_in_base"))


@dataclass(frozen=True)
class Settings:
    """One consistent set of values: what a frame is processed with (swapped as a whole)."""

    stereo: StereoParams | None
    options: NodeOptions
    output: OutputOptions = field(default_factory=OutputOptions)


def output_options(values: Mapping[str, Any]) -> OutputOptions:
    """OutputOptions from looser values (text from the command line, YAML), validated."""
    return OutputOptions(**coerced(OutputOptions, values)).validate()


def list_option_names() -> set[str]:
    return {f.name for cls in OPTION_CLASSES for f in dataclasses.fields(cls) if spec_of(f).length}


def list_value(name: str, text: str) -> Any:
    """A list option's value given as text (`--set`, a flag, `ros2 param set` mixing integers and doubles),
    read as YAML as ROS reads `-p name:=[0, 0, 1]`; the option's field checks what it holds."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        msg = f"{name}: cannot read {text!r} as a YAML list ({' '.join(str(exc).split())})"
        raise ParameterError(msg) from exc


def node_options(values: Mapping[str, Any]) -> NodeOptions:
    """NodeOptions from looser values (a parameter file, flags), validated; other names are ignored."""
    return NodeOptions(**coerced(NodeOptions, values)).validate()


# Parameters every rclpy node has, and the prefix of rclpy's per-topic QoS overrides (a node checks those
# against its own topics once its endpoints exist: ros/qos.py `unused_overrides_line`).
ROS_BUILTINS = ("use_sim_time", "start_type_description_service")
ROS_BUILTIN_PREFIX = "qos_overrides."


def known_parameters() -> set[str]:
    """Every parameter name of any stereo_depth node (a node ignores the ones it does not declare)."""
    return {"profile", *COMPAT_ALIASES, *(f.name for cls in OPTION_CLASSES for f in dataclasses.fields(cls))}


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
