"""One frame from four input messages to output messages: the one path of the live nodes and `process`.

stereo_node's two worker stages, disparity_node, point_cloud_node, `stereo-depth process` and
`check-calibration` all call these functions, so live and offline outputs agree by construction,
option for option:

- `decode_frame`: a `StereoSet` (the synchronizer's four inputs, by name) -> `StereoFrame`, sizes
  checked and every error naming the input it is about;
- `match_frame`, then `frame_outputs`: the two stages in order, the node's and `process`'s:
- `image_outputs`: what matching gives (left/image_rect(_color), disparity, confidence);
- `geometry_outputs`: what depth gives (depth, its compressedDepth, points2, points2_clearing), one
  cloud builder for all.

ROS-free: messages of either flavour (rclpy or rosbags) go in, messages of the caller's `MessageTypes`
come out (see stereo_depth.messages).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import Any, NamedTuple, TypeVar

import cv2
import numpy as np

from stereo_depth.core.camera import StereoCamera, rectified_input, with_baseline
from stereo_depth.core.geometry import Rays
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import StereoPipeline, StereoResult, output_params
from stereo_depth.core.temporal import TemporalFilter
from stereo_depth.errors import CalibrationError, ImageError, StereoDepthError
from stereo_depth.mask_image import read_mask
from stereo_depth.messages import (
    DEFAULT_MAX_PIXELS,
    MessageBuffer,
    MessageTypes,
    array_to_image,
    camera_info_from_msg,
    camera_info_to_msg,
    compressed_to_pipeline,
    depth_to_cloud,
    depth_to_compressed_depth,
    disparity_to_msg,
    image_to_pipeline,
    stamp_to_ns,
)
from stereo_depth.options import OutputOptions
from stereo_depth.sync import StereoSet

T = TypeVar("T")

# Output names, relative to the node's namespace (the topics stereo_node publishes).
IMAGE_OUTPUTS = ("left/image_rect", "left/image_rect_color", "disparity", "confidence")
GEOMETRY_OUTPUTS = ("depth", "depth/camera_info", "depth/compressedDepth", "points2", "points2_clearing")
OUTPUTS = (*IMAGE_OUTPUTS, *GEOMETRY_OUTPUTS)
# what stereo_node publishes with its defaults and `process` writes unless told: not the two for navigation
DEFAULT_OUTPUTS = tuple(name for name in OUTPUTS if name not in ("depth/compressedDepth", "points2_clearing"))
CLOUDS = frozenset({"points2", "points2_clearing"})  # what points_max_rate thins

MM_PER_M = 1000.0
UINT16_MAX = 65535


class InputNames(NamedTuple):
    """What errors call each input of a StereoSet: its topic live and offline, these words otherwise."""

    left_image: str = "left image"
    left_info: str = "left camera_info"
    right_image: str = "right image"
    right_info: str = "right camera_info"


INPUT_NAMES = InputNames()  # when the caller has no topic names


@dataclass(frozen=True)
class StereoFrame:
    """The inputs of one frame, decoded: what the pipeline matches and the outputs copy."""

    stamp_ns: int
    header: Any  # the left image's header, copied onto every output
    left: np.ndarray  # as the pipeline takes them: mono (8 or 16 bit) or BGR
    right: np.ndarray | None  # None: the set had no right image (point_cloud_node reads a disparity instead)
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
    releases the GIL, so a node keeps receiving meanwhile)."""
    if not hasattr(msg, "encoding"):
        return compressed_to_pipeline(msg, max_pixels)
    return image_to_pipeline(msg, max_pixels)


def frame_camera(
    pipeline: StereoPipeline,
    left_info: Any,
    right_info: Any,
    names: tuple[str, str],
    *,
    rectified: bool,
    baseline: float = 0.0,
) -> StereoCamera:
    """The pipeline's cached StereoCamera for two camera_info messages; errors name both.

    `rectified`: the images are rectified already, so a camera_info with only P set will do;
    `baseline` (metres, 0 = as published) replaces the right P[0,3] the driver got wrong."""
    left = named(names[0], camera_info_from_msg, left_info)
    right = named(names[1], camera_info_from_msg, right_info)
    if rectified:
        left, right = rectified_input(left), rectified_input(right)
    if baseline > 0:
        right = with_baseline(right, baseline)
    try:
        return pipeline.camera_for(left, right)
    except StereoDepthError as exc:
        raise type(exc)(f"{exc} (left = {names[0]}, right = {names[1]})") from exc


def decode_frame(
    inputs: StereoSet,
    pipeline: StereoPipeline,
    options: OutputOptions,
    *,
    rectified: bool,
    names: InputNames = INPUT_NAMES,
) -> StereoFrame:
    """A matched set's images and calibration, sizes checked; `names` (the topics) name the input each
    error is about, so a user knows which driver to fix."""
    if options.swap_left_right:
        inputs, names = swapped(inputs), swapped(names)
    left = named(names.left_image, decode_image, inputs.left_image, options.max_image_pixels)
    (lh, lw), images, right = left.shape[:2], f"{names.left_image} is", None
    if inputs.right_image is not None:
        right = named(names.right_image, decode_image, inputs.right_image, options.max_image_pixels)
        rh, rw = right.shape[:2]
        if (lh, lw) != (rh, rw):
            msg = (
                f"{names.left_image} is {lw}x{lh} but {names.right_image} is {rw}x{rh}; both cameras must "
                "stream one resolution (check each driver's mode, binning and ROI)"
            )
            raise ImageError(msg)
        images = f"{names.left_image} and {names.right_image} are"
    camera = frame_camera(
        pipeline,
        inputs.left_info,
        inputs.right_info,
        (names.left_info, names.right_info),
        rectified=rectified,
        baseline=options.baseline,
    )
    if (lw, lh) != (camera.width, camera.height):
        msg = (
            f"{images} {lw}x{lh} but {names.left_info} and {names.right_info} "
            f"say {camera.width}x{camera.height}; publish the calibration of this camera mode"
        )
        raise CalibrationError(msg)
    header = inputs.left_image.header
    return StereoFrame(stamp_to_ns(header.stamp), header, left, right, camera, rectified)


SwappableT = TypeVar("SwappableT", StereoSet, InputNames)


def swapped(inputs: SwappableT) -> SwappableT:
    """A stereo set, or its names, read the other way round (swap_left_right)."""
    other = {
        "left_image": inputs.right_image,
        "left_info": inputs.right_info,
        "right_image": inputs.left_image,
        "right_info": inputs.left_info,
    }
    if isinstance(inputs, InputNames):
        return inputs._replace(**other)
    return dataclasses.replace(inputs, **other)


def camera_fixes(options: OutputOptions) -> str | None:
    """The line a node or `process` logs once at start when the user corrects the driver's inputs."""
    fixes = []
    if options.baseline > 0:
        fixes.append(f"baseline {options.baseline} m replaces the right camera_info's P[0,3]")
    if options.swap_left_right:
        fixes.append("swap_left_right: the left topics are read as the right camera and the right ones as the left")
    return "; ".join(fixes) if fixes else None


def match_frame(pipeline: StereoPipeline, frame: StereoFrame, names: InputNames = INPUT_NAMES) -> StereoResult:
    """Rectify, match and filter one frame (`pipeline.match`); errors name both image inputs."""
    assert frame.right is not None, "a frame without a right image cannot be matched"
    try:
        return pipeline.match(frame.left, frame.right, frame.camera, rectified=frame.rectified)
    except StereoDepthError as exc:
        raise type(exc)(f"{names.left_image} and {names.right_image}: {exc}") from exc


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
    types: MessageTypes,
    header: Any,
    disparity: np.ndarray,
    camera: StereoCamera,
    params: StereoParams,
    buffer: MessageBuffer | None = None,
) -> Any:
    """DisparityImage with the frame's real valid window and resolution (1/16 px per downsample step),
    its data in `buffer` when given."""
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
        buffer=buffer,
    )


def valid_region(disparity: np.ndarray) -> tuple[int, int, int, int]:
    """(x, y, width, height) of the smallest window holding every valid disparity of this frame, for
    DisparityImage.valid_window; (0, 0, 0, 0) when none is valid.

    Not OpenCV's getValidDisparityROI: SGBM fills rows and columns outside it, census_sgm fills the left
    border and hole filling anything, so only the frame itself says where its valid pixels are.
    """
    x, y, width, height = cv2.boundingRect(np.isfinite(disparity).view(np.uint8))  # of the non-zero pixels
    return int(x), int(y), int(width), int(height)


def image_outputs(
    types: MessageTypes,
    header: Any,
    result: StereoResult,
    params: StereoParams,
    wanted: Collection[str],
    disparity_buffer: MessageBuffer | None = None,
) -> dict[str, Any]:
    """The messages matching gives, by output name: those in `wanted` that this frame has (the colour
    image needs a colour input, confidence a matcher that gives one); the disparity's data in
    `disparity_buffer` when given."""
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
            messages[name] = disparity_message(types, header, result.disparity, result.camera, params, disparity_buffer)
            continue
        pixels, encoding = arrays[name]
        if pixels is not None:
            messages[name] = array_to_image(types, header, pixels, encoding)
    return messages


# ---------------------------------------------------------------- geometry outputs


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
        """`wanted` without the clouds when this frame's clouds are not due."""
        if CLOUDS & set(wanted) and not self.due(stamp_ns, options.points_max_rate):
            return frozenset(wanted) - CLOUDS
        return frozenset(wanted)


class OutputState:
    """What one stream of frames keeps between frames for its outputs: the rectified mask, the
    organized cloud's and the disparity's bytes, the stamp of the last cloud (points_max_rate) and the
    temporal filter's history (touched only where frames are in stamp order: `filter_over_time`)."""

    def __init__(self) -> None:
        self.temporal = TemporalFilter()
        self.masks = RectifiedMasks()
        self.disparity_buffer = MessageBuffer()  # filled and published under the node's output order lock
        self.cloud_buffer = MessageBuffer()
        self.clearing_buffer = MessageBuffer()  # points2_clearing's own: points2 may still hold the other
        self.cloud_rate = CloudRate()


class Geometry(NamedTuple):
    """What depth and points2 are built from: one frame's depth with its calibration and colour."""

    depth: np.ndarray  # float32 metres, NaN invalid, at the output size
    camera: StereoCamera  # the rectified calibration of that size
    rays: Rays
    image: np.ndarray  # rectified left, BGR or grey: the cloud's colour
    raw_camera: StereoCamera  # the input calibration, at the input size (the mask is drawn in its raw image)
    at_min_disparity: np.ndarray | None = None  # matched at the smallest disparity searched (points2_clearing)


def result_geometry(pipeline: StereoPipeline, frame: StereoFrame, result: StereoResult) -> Geometry:
    """Depth of a `match` result (`pipeline.add_geometry`; the points go straight into the cloud)."""
    assert result.camera is not None
    pipeline.add_geometry(result, want_points=False)
    assert result.depth is not None
    image = result.left_rect_color if result.left_rect_color is not None else result.left_rect
    params = pipeline.params
    step = 1 if params.downsample_output == "processed" else params.downsample  # one matcher step, output px
    with np.errstate(invalid="ignore"):  # NaN: not matched
        saturated = result.disparity < np.float32(output_params(params).min_disparity + step)
    rays = pipeline.rays_for(result.camera)
    return Geometry(result.depth, result.camera, rays, image, frame.camera, saturated)


def clearing_depth(geometry: Geometry, options: OutputOptions, masks: RectifiedMasks) -> np.ndarray:
    """The depth of points2_clearing (NaN elsewhere): pixels matched beyond max_depth or at the smallest
    disparity searched (as far as the matcher sees, or farther: their depth may be infinite), each at
    its depth clamped to clearing_max_depth. Such pixels never reach depth or points2 when beyond
    max_depth; the mask and min_depth still hold them back, and so does glare (`near_saturation`). Call
    before `limit_depth`."""
    depth = geometry.depth
    with np.errstate(invalid="ignore"):
        far = depth > np.float32(options.max_depth) if options.max_depth > 0 else np.zeros(depth.shape, bool)
        if geometry.at_min_disparity is not None:
            far |= geometry.at_min_disparity
        if options.min_depth > 0:
            far &= ~(depth < np.float32(options.min_depth))
    far &= ~near_saturation(geometry.image)
    if options.mask_image:
        far &= masks.get(options.mask_image, geometry.raw_camera, depth.shape)
    clearing = np.full(depth.shape, np.nan, np.float32)
    clearing[far] = np.fmin(depth[far], np.float32(options.clearing_max_depth))  # fmin: infinite (NaN) -> the limit
    return clearing


def near_saturation(image: np.ndarray) -> np.ndarray:
    """Pixels within one pixel of a saturated one (any channel at the type's maximum) in the rectified
    left image. Glare is white without texture, so a matcher's disparity there is arbitrary: SGBM puts
    2,700-3,600 pixels of each bundled EuRoC frame (a room) at the smallest disparity, more than half of
    them in or beside glare. A clearing ray from one would clear real obstacles along it, so none is cast."""
    top = np.iinfo(image.dtype).max
    saturated = (image >= top) if image.ndim == 2 else (image >= top).any(axis=2)
    return cv2.dilate(saturated.view(np.uint8), np.ones((3, 3), np.uint8)) > 0


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


def depth_pixels(depth: np.ndarray, encoding: str) -> np.ndarray:
    """32FC1 metres (NaN invalid) or REP 118's 16UC1 millimetres (0 invalid; beyond 65.535 m too)."""
    if encoding == "32FC1":
        return depth
    with np.errstate(invalid="ignore"):
        mm = np.rint(depth.astype(np.float64) * MM_PER_M)
        mm[~(mm <= UINT16_MAX)] = 0  # NaN and unrepresentable depths
    return mm.astype(np.uint16)


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
    clearing = clearing_depth(geometry, options, state.masks) if "points2_clearing" in wanted else None
    limit_depth(geometry, options, state.masks)
    messages: dict[str, Any] = {}
    if {"depth", "depth/compressedDepth"} & set(wanted):
        pixels = depth_pixels(geometry.depth, options.depth_encoding)
    if "depth" in wanted:
        messages["depth"] = array_to_image(types, header, pixels, options.depth_encoding)
    if "depth/compressedDepth" in wanted:
        messages["depth/compressedDepth"] = depth_to_compressed_depth(
            types,
            header,
            pixels,
            options.depth_encoding,
            codec=options.compressed_depth_format,
            depth_max=options.compressed_depth_max_depth,
            depth_quantization=options.compressed_depth_quantization,
            png_level=options.compressed_depth_png_level,
        )
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
    if clearing is not None:  # the points only, no colour: a costmap traces rays to them
        messages["points2_clearing"] = depth_to_cloud(
            types,
            header,
            clearing,
            geometry.rays,
            avoid_padding=options.avoid_point_cloud_padding,
            buffer=state.clearing_buffer,
            organized=False,
        )
    return messages


# ---------------------------------------------------------------- the two stages in order


def run_now(stage: Callable[[], None]) -> None:
    stage()


def frame_outputs(
    types: MessageTypes,
    pipeline: StereoPipeline,
    frame: StereoFrame,
    result: StereoResult,
    params: StereoParams,
    output: OutputOptions,
    wanted: Collection[str],
    state: OutputState,
    send_images: Callable[[dict[str, Any]], None],
    send_cloud: Callable[[dict[str, Any], Geometry | None], None],
    *,
    run_cloud_stage: Callable[[Callable[[], None]], None] = run_now,
    with_geometry: bool = False,
) -> None:
    """What follows `match_frame`, in stereo_node's order, for the node and `process` alike: the image
    outputs in `wanted` go to `send_images` at once; then the cloud stage builds those of depth,
    depth/camera_info and points2 in `wanted` that are due (points_max_rate), with the geometry they
    come from, for `send_cloud`, which ends the frame. `run_cloud_stage` runs that stage: at once
    (`process`) or on the node's second thread. Nothing due (and no `with_geometry`, which a PLY
    needs): `send_cloud({}, None)` at once.
    """
    filter_over_time(state.temporal, frame, result, output)
    send_images(image_outputs(types, frame.header, result, params, wanted, state.disparity_buffer))
    if frame.camera.no_depth_reason is not None:  # no baseline: disparity only (the caller warns once)
        send_cloud({}, None)
        return
    due = state.cloud_rate.wanted([name for name in GEOMETRY_OUTPUTS if name in wanted], frame.stamp_ns, output)
    if not due and not with_geometry:
        send_cloud({}, None)
        return

    def cloud_stage() -> None:
        geometry = result_geometry(pipeline, frame, result)  # times "depth"
        start = time.perf_counter()
        messages = geometry_outputs(types, frame.header, geometry, output, due, state)
        result.timings_ms["points"] = (time.perf_counter() - start) * 1000.0
        send_cloud(messages, geometry)

    run_cloud_stage(cloud_stage)
