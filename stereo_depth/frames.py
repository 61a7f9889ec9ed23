"""One frame from four input messages to output messages: the one path of the live nodes and `process`.

stereo_node's two worker stages, disparity_node, point_cloud_node and `stereo-depth process` all call
these functions, so live and offline outputs agree by construction, option for option:

- `decode_frame`: (left image, left info, right image, right info) -> `StereoFrame`, sizes checked and
  every error naming the input it is about;
- `image_outputs`: what matching gives (left/image_rect(_color), disparity, confidence);
- `geometry_outputs`: what depth gives (depth, points2), one cloud builder for all.

ROS-free: messages of either flavour (rclpy or rosbags) go in, messages of the caller's `MessageTypes`
come out (see messages.py).
"""

from __future__ import annotations

import dataclasses
import functools
import threading
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import cv2
import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.geometry import Rays
from stereo_depth.core.params import StereoParams, _spec, coerce
from stereo_depth.core.pipeline import StereoPipeline, StereoResult, output_params
from stereo_depth.core.temporal import TemporalFilter, TemporalSettings
from stereo_depth.errors import CalibrationError, ImageError, ParameterError, StereoDepthError
from stereo_depth.messages import (
    DEFAULT_MAX_PIXELS,
    CloudBuffer,
    MessageTypes,
    array_to_image,
    camera_info_from_msg,
    camera_info_to_msg,
    compressed_to_pipeline,
    depth_to_cloud,
    disparity_to_msg,
    image_to_pipeline,
    stamp_to_ns,
)

T = TypeVar("T")

# Output names, relative to the node's namespace (the topics stereo_node publishes).
IMAGE_OUTPUTS = ("left/image_rect", "left/image_rect_color", "disparity", "confidence")
GEOMETRY_OUTPUTS = ("depth", "depth/camera_info", "points2")
OUTPUTS = (*IMAGE_OUTPUTS, *GEOMETRY_OUTPUTS)

DEPTH_ENCODINGS = ("32FC1", "16UC1")
MM_PER_M = 1000.0
UINT16_MAX = 65535

# How an input is named in errors when the caller has no topic names.
INPUT_NAMES = ("left image", "left camera_info", "right image", "right camera_info")


@dataclass(frozen=True)
class OutputOptions:
    """How outputs are built, live and offline alike (ROS parameters of the nodes, `process --set`)."""

    use_color: bool = field(default=True, metadata=_spec("Add PCL-style packed rgb to points2"))
    avoid_point_cloud_padding: bool = field(
        default=False, metadata=_spec("Pack points2 tightly (16-byte points) instead of stereo_image_proc's 32")
    )
    max_image_pixels: int = field(
        default=DEFAULT_MAX_PIXELS,
        metadata=_spec("Refuse input images with more pixels than this (protects memory)", 1, 1 << 28, 1),
    )
    depth_encoding: str = field(
        default="32FC1",
        metadata=_spec(
            "depth image encoding: 32FC1 (metres, NaN invalid) or 16UC1 (millimetres, 0 invalid, REP 118; "
            "beyond 65.535 m invalid)"
        ),
    )
    min_depth: float = field(
        default=0.0, metadata=_spec("Nearer points are invalid in depth and points2, metres (0 = no limit)", 0.0, 1e4)
    )
    max_depth: float = field(
        default=0.0,
        metadata=_spec("Farther points are invalid in depth and points2, metres (0 = no limit)", 0.0, 1e4),
    )
    mask_image: str = field(
        default="",
        metadata=_spec(
            "Path of an image the size of the raw left image: where it is zero (robot body, bumper, lens "
            "hood) nothing is output in depth or points2. Empty: no mask"
        ),
    )
    organized_cloud: bool = field(
        default=True,
        metadata=_spec(
            "points2 organized like the image (stereo_image_proc's layout, NaN invalid), or false: the valid "
            "points only (height 1, is_dense, no NaN)"
        ),
    )
    cloud_voxel_size: float = field(
        default=0.0,
        metadata=_spec("With organized_cloud false: one point per voxel of this edge, metres (0 = off)", 0.0, 100.0),
    )
    points_max_rate: float = field(
        default=0.0,
        metadata=_spec("Publish points2 at most this often, Hz, judged by stamps (0 = every frame)", 0.0, 1000.0),
    )

    temporal_filter: bool = field(
        default=False,
        metadata=_spec(
            "Filter the disparity over time before depth and points2: a pixel is output only when it agrees "
            "with temporal_persistence of the last temporal_history frames (no ghost points)"
        ),
    )
    temporal_alpha: float = field(
        default=0.4,
        metadata=_spec("Temporal filter: the newest frame's weight in the per-pixel exponential average", 0.01, 1.0),
    )
    temporal_delta: float = field(
        default=2.0,
        metadata=_spec(
            "Temporal filter: values within this many px agree (one surface); a value farther from the "
            "pixel's newest restarts its average",
            0.0,
            1e3,
        ),
    )
    temporal_persistence: int = field(
        default=4,
        metadata=_spec("Temporal filter: frames of temporal_history a pixel must agree in to be output", 1, 8, 1),
    )
    temporal_history: int = field(default=8, metadata=_spec("Temporal filter: frames remembered per pixel", 1, 8, 1))
    temporal_motion_reset: float = field(
        default=0.0,
        metadata=_spec(
            "Temporal filter: restart every pixel when more than this share of them changed at once "
            "(the camera moved fast; 0 = off)",
            0.0,
            1.0,
        ),
    )

    @property
    def temporal(self) -> TemporalSettings:
        return TemporalSettings(
            self.temporal_alpha,
            self.temporal_delta,
            self.temporal_persistence,
            self.temporal_history,
            self.temporal_motion_reset,
        )

    def validate(self) -> OutputOptions:
        for f in dataclasses.fields(self):
            spec, value = f.metadata, getattr(self, f.name)
            if spec.get("min") is not None and not spec["min"] <= value <= spec["max"]:
                msg = f"{f.name} {value} is outside [{spec['min']}, {spec['max']}]"
                raise ParameterError(msg)
        checks = [
            (
                self.depth_encoding in DEPTH_ENCODINGS,
                f"depth_encoding '{self.depth_encoding}' must be one of {', '.join(DEPTH_ENCODINGS)}",
            ),
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
        self.temporal.validate()
        return self


def output_option_names() -> list[str]:
    return [f.name for f in dataclasses.fields(OutputOptions)]


def make_output_options(values: Mapping[str, Any]) -> OutputOptions:
    """OutputOptions from looser values (text from the command line, YAML), validated."""
    kinds = {f.name: f.type for f in dataclasses.fields(OutputOptions)}
    return OutputOptions(**{name: coerce(name, value, kinds[name]) for name, value in values.items()}).validate()


@dataclass(frozen=True)
class StereoFrame:
    """The four inputs of one frame, decoded: what the pipeline matches and the outputs copy."""

    stamp_ns: int
    header: Any  # the left image's header, copied onto every output
    left: np.ndarray  # as the pipeline takes them: mono (8 or 16 bit) or BGR
    right: np.ndarray
    camera: StereoCamera  # the pipeline's cached camera for this calibration
    rectified: bool  # the images are rectified already (image_rect inputs)


def named(name: str, convert: Callable[..., T], *args: Any) -> T:
    """`convert(*args)`, with `name` (a topic) in front of any error it raises."""
    try:
        return convert(*args)
    except StereoDepthError as exc:
        raise type(exc)(f"{name}: {exc}") from exc


def decode_image(msg: Any, max_pixels: int = DEFAULT_MAX_PIXELS) -> np.ndarray:
    """An input image message as the pipeline takes it: the one place input images are decoded.

    A sensor_msgs/CompressedImage (it has a format, no encoding: image_transport's `compressed`, JPEG or
    PNG) is decoded here, once per image, on whichever thread processes the frame (cv2.imdecode
    releases the GIL, so a node's executor keeps receiving meanwhile)."""
    if not hasattr(msg, "encoding"):
        return compressed_to_pipeline(msg, max_pixels)
    return image_to_pipeline(msg, max_pixels)


def frame_camera(pipeline: StereoPipeline, left_info: Any, right_info: Any, names: tuple[str, str]) -> StereoCamera:
    """The pipeline's cached StereoCamera for two camera_info messages; errors name both."""
    left = named(names[0], camera_info_from_msg, left_info)
    right = named(names[1], camera_info_from_msg, right_info)
    try:
        return pipeline.camera_for(left, right)
    except StereoDepthError as exc:
        raise type(exc)(f"{exc} (left = {names[0]}, right = {names[1]})") from exc


def decode_frame(
    messages: Sequence[Any],
    pipeline: StereoPipeline,
    options: OutputOptions,
    *,
    rectified: bool,
    names: Sequence[str] = INPUT_NAMES,
) -> StereoFrame:
    """(left image, left info, right image, right info) -> StereoFrame; `names` (the topics) name the
    input each error is about, so a user knows which driver to fix."""
    left_msg, left_info, right_msg, right_info = messages
    left = named(names[0], decode_image, left_msg, options.max_image_pixels)
    right = named(names[2], decode_image, right_msg, options.max_image_pixels)
    camera = frame_camera(pipeline, left_info, right_info, (names[1], names[3]))
    (lh, lw), (rh, rw) = left.shape[:2], right.shape[:2]
    if (lh, lw) != (rh, rw):
        msg = (
            f"{names[0]} is {lw}x{lh} but {names[2]} is {rw}x{rh}; both cameras must "
            "stream one resolution (check each driver's mode, binning and ROI)"
        )
        raise ImageError(msg)
    if (lw, lh) != (camera.width, camera.height):
        msg = (
            f"{names[0]} and {names[2]} are {lw}x{lh} but {names[1]} and {names[3]} "
            f"say {camera.width}x{camera.height}; publish the calibration of this camera mode"
        )
        raise CalibrationError(msg)
    header = left_msg.header
    return StereoFrame(stamp_to_ns(header.stamp), header, left, right, camera, rectified)


def match_frame(pipeline: StereoPipeline, frame: StereoFrame, names: Sequence[str] = INPUT_NAMES) -> StereoResult:
    """Rectify, match and filter one frame (`pipeline.match`); errors name both image inputs."""
    try:
        return pipeline.match(frame.left, frame.right, frame.camera, rectified=frame.rectified)
    except StereoDepthError as exc:
        raise type(exc)(f"{names[0]} and {names[2]}: {exc}") from exc


def filter_over_time(
    temporal: TemporalFilter, frame: StereoFrame, result: StereoResult, options: OutputOptions
) -> None:
    """`temporal_filter`: the frame's disparity replaced by its temporally filtered one (timed as stage
    "temporal"), so disparity, depth and points2 all carry it. Call it once per frame in stamp order,
    after matching and before the outputs; off, it forgets what it had seen."""
    if not options.temporal_filter:
        temporal.reset()
        return
    start = time.perf_counter()
    result.disparity = temporal.apply(
        result.disparity, result.confidence, frame.stamp_ns, frame.camera.key(), options.temporal
    )
    result.timings_ms["temporal"] = (time.perf_counter() - start) * 1000.0


# ---------------------------------------------------------------- match outputs


def disparity_message(
    types: MessageTypes, header: Any, disparity: np.ndarray, camera: StereoCamera, params: StereoParams
) -> Any:
    """DisparityImage with the frame's real valid window and resolution (1/16 px per downsample step)."""
    params = output_params(params)  # the disparity's own size and range (downsample_output)
    return disparity_to_msg(
        types,
        header,
        disparity,
        camera,
        params.min_disparity,
        params.disparity_range,
        valid_region(disparity),
        delta_d=params.downsample / 16.0,
    )


def valid_region(disparity: np.ndarray) -> tuple[int, int, int, int]:
    """(x, y, width, height) of the smallest window holding every valid disparity of this frame, for
    DisparityImage.valid_window; (0, 0, 0, 0) when none is valid.

    Not OpenCV's getValidDisparityROI: SGBM fills rows and columns outside it, census_sgm fills the left
    border and hole filling anything, so only the frame itself says where its valid pixels are.
    """
    valid = np.isfinite(disparity)
    rows, columns = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    if rows.size == 0:
        return 0, 0, 0, 0
    return int(columns[0]), int(rows[0]), int(columns[-1] - columns[0] + 1), int(rows[-1] - rows[0] + 1)


def image_outputs(
    types: MessageTypes, header: Any, result: StereoResult, params: StereoParams, wanted: Collection[str]
) -> dict[str, Any]:
    """The messages matching gives, by output name: those in `wanted` that this frame has (the colour
    image needs a colour input, confidence a matcher that gives one)."""
    assert result.camera is not None
    arrays: dict[str, tuple[np.ndarray | None, str | None]] = {
        "left/image_rect": (result.left_rect, None),
        "left/image_rect_color": (result.left_rect_color, None),
        "confidence": (result.confidence, "32FC1"),
    }
    messages: dict[str, Any] = {}
    for name in IMAGE_OUTPUTS:
        if name not in wanted:
            continue
        if name == "disparity":
            messages[name] = disparity_message(types, header, result.disparity, result.camera, params)
            continue
        pixels, encoding = arrays[name]
        if pixels is not None:
            messages[name] = array_to_image(types, header, pixels, encoding)
    return messages


# ---------------------------------------------------------------- geometry outputs


def read_mask(path: str) -> np.ndarray:
    """The mask image as bool (True: may be output), read once per file version."""
    try:
        stat = Path(path).stat()
    except OSError as exc:
        msg = f"mask_image {path}: cannot read it ({exc.strerror})"
        raise ParameterError(msg) from exc
    return _read_mask(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=4)
def _read_mask(path: str, mtime_ns: int, size: int) -> np.ndarray:
    del mtime_ns, size  # the cache key: a changed file is read again
    image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if image is None:
        msg = f"mask_image {path}: not an image OpenCV can read (use a PNG, zero where nothing is output)"
        raise ParameterError(msg)
    mask: np.ndarray = image > 0
    mask.setflags(write=False)
    return mask


class RectifiedMasks:
    """The mask in the frame of the outputs: rectified with the left camera's maps (the mask is drawn on
    the raw image), then shrunk to the output size. A pixel is kept only when every raw pixel it is
    interpolated from is kept, so no masked pixel leaks out at the mask's edges. Built once per mask,
    calibration and size."""

    def __init__(self) -> None:
        self._cached: tuple[tuple[object, ...], np.ndarray] | None = None
        self._lock = threading.Lock()

    def get(self, path: str, camera: StereoCamera, shape: tuple[int, int]) -> np.ndarray:
        raw = read_mask(path)
        key = (path, id(raw), camera.key(), shape)
        with self._lock:
            if self._cached is None or self._cached[0] != key:
                self._cached = (key, _rectified_mask(path, raw, camera, shape))
            return self._cached[1]


def _rectified_mask(path: str, raw: np.ndarray, camera: StereoCamera, shape: tuple[int, int]) -> np.ndarray:
    if raw.shape != (camera.height, camera.width):
        msg = (
            f"mask_image {path} is {raw.shape[1]}x{raw.shape[0]} but the left camera is "
            f"{camera.width}x{camera.height}; draw the mask on a raw left image of this camera mode"
        )
        raise ImageError(msg)
    kept: np.ndarray = raw.astype(np.float32)
    if camera.needs_rectification("left"):
        map1, map2 = camera.rectification_maps("left")
        kept = cv2.remap(kept, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
    if kept.shape != shape:
        kept = cv2.resize(kept, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return np.asarray(kept > 0.999)


class CloudRate:
    """`points_max_rate`: whether this frame's cloud is due, judged by stamps (so a bag gives the same
    clouds offline as replayed into a node). A stamp that goes back (a looping bag) starts afresh."""

    def __init__(self) -> None:
        self._last_ns: int | None = None

    def due(self, stamp_ns: int, max_rate: float) -> bool:
        if max_rate <= 0:
            return True
        last = self._last_ns
        if last is not None and last <= stamp_ns < last + round(1e9 / max_rate):
            return False
        self._last_ns = stamp_ns
        return True

    def wanted(self, wanted: Collection[str], stamp_ns: int, options: OutputOptions) -> frozenset[str]:
        """`wanted` without points2 when this frame's cloud is not due."""
        if "points2" in wanted and not self.due(stamp_ns, options.points_max_rate):
            return frozenset(wanted) - {"points2"}
        return frozenset(wanted)


class OutputState:
    """What one stream of frames keeps between frames for its outputs: the rectified mask, the
    organized cloud's bytes, the stamp of the last cloud (points_max_rate) and the temporal filter's
    history (touched only where frames are in stamp order: `filter_over_time`)."""

    def __init__(self) -> None:
        self.temporal = TemporalFilter()
        self.masks = RectifiedMasks()
        self.cloud_buffer = CloudBuffer()
        self.cloud_rate = CloudRate()


class Geometry(NamedTuple):
    """What depth and points2 are built from: one frame's depth with its calibration and colour."""

    depth: np.ndarray  # float32 metres, NaN invalid, at the output size
    camera: StereoCamera  # the rectified calibration of that size
    rays: Rays
    image: np.ndarray  # rectified left, BGR or grey: the cloud's colour
    raw_camera: StereoCamera  # the input calibration, at the input size (the mask is drawn in its raw image)


def result_geometry(pipeline: StereoPipeline, frame: StereoFrame, result: StereoResult) -> Geometry:
    """Depth of a `match` result (`pipeline.add_geometry`; the points go straight into the cloud)."""
    assert result.camera is not None
    pipeline.add_geometry(result, want_points=False)
    assert result.depth is not None
    image = result.left_rect_color if result.left_rect_color is not None else result.left_rect
    return Geometry(result.depth, result.camera, pipeline.rays_for(result.camera), image, frame.camera)


def limit_depth(geometry: Geometry, options: OutputOptions, masks: RectifiedMasks) -> None:
    """min_depth, max_depth and mask_image: the pixels they exclude become invalid (NaN) in the depth,
    in place, so neither depth nor points2 has them; the disparity stays as matched."""
    depth = geometry.depth
    with np.errstate(invalid="ignore"):
        if options.min_depth > 0:
            depth[depth < np.float32(options.min_depth)] = np.nan
        if options.max_depth > 0:
            depth[depth > np.float32(options.max_depth)] = np.nan
    if options.mask_image:
        depth[~masks.get(options.mask_image, geometry.raw_camera, depth.shape)] = np.nan


def depth_image(types: MessageTypes, header: Any, depth: np.ndarray, encoding: str) -> Any:
    """32FC1 metres (NaN invalid) or REP 118's 16UC1 millimetres (0 invalid; beyond 65.535 m too)."""
    if encoding == "32FC1":
        return array_to_image(types, header, depth, "32FC1")
    with np.errstate(invalid="ignore"):
        mm = np.rint(depth.astype(np.float64) * MM_PER_M)
        mm[~(mm <= UINT16_MAX)] = 0  # NaN and unrepresentable depths
    return array_to_image(types, header, mm.astype(np.uint16), "16UC1")


def depth_camera_info(types: MessageTypes, header: Any, camera: StereoCamera) -> Any:
    """The depth image's calibration: the rectified left model at the depth's size (K = P's left 3x3,
    D = 0, R = I), which is what `StereoCamera.shrunk` builds (factor 1: the full-size one)."""
    rectified = camera.shrunk(1).left
    return camera_info_to_msg(types, header, dataclasses.replace(rectified, frame_id=str(header.frame_id)))


def geometry_outputs(
    types: MessageTypes,
    header: Any,
    geometry: Geometry,
    options: OutputOptions,
    wanted: Collection[str],
    state: OutputState,
) -> dict[str, Any]:
    """depth, depth/camera_info and points2 by output name, those in `wanted`, with the depth limits
    and the mask applied. An organized points2 has its x, y, z computed straight into the message.

    `state`: the caller's own for this stream; its cloud buffer is reused frame to frame, so hand the
    cloud on (publish, write) before the next call.
    """
    limit_depth(geometry, options, state.masks)
    messages: dict[str, Any] = {}
    if "depth" in wanted:
        messages["depth"] = depth_image(types, header, geometry.depth, options.depth_encoding)
    if "depth/camera_info" in wanted:
        messages["depth/camera_info"] = depth_camera_info(types, header, geometry.camera)
    if "points2" in wanted:
        color = geometry.image if options.use_color else None
        messages["points2"] = depth_to_cloud(
            types,
            header,
            geometry.depth,
            geometry.rays,
            color,
            avoid_padding=options.avoid_point_cloud_padding,
            buffer=state.cloud_buffer,
            organized=options.organized_cloud,
            voxel_size=options.cloud_voxel_size,
        )
    return messages
