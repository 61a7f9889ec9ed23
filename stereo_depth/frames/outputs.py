"""What a frame's outputs are built from and how: the image messages of matching, the temporal filter,
and the messages of depth (depth limits, mask, clearing points, points2) with the state a stream keeps
for them between frames."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Collection
from typing import Any, NamedTuple

import cv2
import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.geometry import Rays, disparity_to_depth
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import (
    StereoPipeline,
    StereoResult,
    nearest_disparity,
    output_params,
    rectified_output,
)
from stereo_depth.core.temporal import CameraMotion, TemporalFilter
from stereo_depth.errors import ImageError
from stereo_depth.frames.decode import StereoFrame
from stereo_depth.frames.odometry import OdometryState
from stereo_depth.mask_image import read_mask
from stereo_depth.messages import (
    MessageBuffer,
    MessageTypes,
    array_to_image,
    camera_info_to_msg,
    depth_to_cloud,
    depth_to_compressed_depth,
    disparity_to_msg,
    make_header,
)
from stereo_depth.options import OutputOptions

# Output names, relative to the node's namespace (the topics stereo_node publishes).
IMAGE_OUTPUTS = (
    "left/image_rect",
    "left/image_rect_color",
    "right/image_rect",
    "right/image_rect_color",
    "disparity",
    "confidence",
)
GEOMETRY_OUTPUTS = ("depth", "depth/camera_info", "depth/compressedDepth", "points2", "points2_clearing")
OUTPUTS = (*IMAGE_OUTPUTS, *GEOMETRY_OUTPUTS)
# what `process` writes unless told: not the two for navigation, nor the right images (for visual odometry)
DEFAULT_OUTPUTS = tuple(
    name
    for name in OUTPUTS
    if name not in ("depth/compressedDepth", "points2_clearing") and not name.startswith("right/")
)
CLOUDS = frozenset({"points2", "points2_clearing"})  # what points_max_rate thins

MM_PER_M = 1000.0
UINT16_MAX = 65535


def filtered_disparity(
    temporal: TemporalFilter,
    frame: StereoFrame,
    result: StereoResult,
    params: StereoParams,
    motion: CameraMotion | None = None,
) -> np.ndarray:
    """`temporal_filter`: the frame's disparity filtered over time, which disparity, depth and points2 all
    carry (the matcher's own stays in `result`). Call it once per frame in stamp order, after matching and
    before the outputs; off, it forgets what it had seen and gives the matcher's disparity. `motion`: where
    the camera was (odometry, frames/odometry.py); None: no odometry."""
    if not params.temporal_filter:
        temporal.reset()
        return result.disparity
    return temporal.apply(
        result.disparity,
        result.confidence,
        frame.stamp_ns,
        frame.camera.key(),
        params.temporal,
        view=result.left_rect,
        motion=motion,
    )


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
    frame: StereoFrame,
    result: StereoResult,
    disparity: np.ndarray,
    params: StereoParams,
    wanted: Collection[str],
    disparity_buffer: MessageBuffer | None = None,
) -> dict[str, Any]:
    """The messages matching gives, by output name: those in `wanted` that this frame has (a colour image
    needs a colour input, confidence a matcher that gives one); `disparity` is the frame's (after the
    temporal filter), its data in `disparity_buffer` when given. Every one carries the frame's stamp; the
    right images carry the right camera's frame_id, the others the left's."""
    assert result.camera is not None
    header = frame.header
    messages: dict[str, Any] = {}
    if "disparity" in wanted:
        messages["disparity"] = disparity_message(types, header, disparity, result.camera, params, disparity_buffer)
    if "confidence" in wanted and result.confidence is not None:
        messages["confidence"] = array_to_image(types, header, result.confidence, "32FC1")
    for side, raw, side_header in (("left", frame.left, header), ("right", frame.right, _right_header(types, frame))):
        matched = result.left_rect if side == "left" else result.right_rect
        if raw is not None and f"{side}/image_rect" in wanted:
            mono = _rectified(frame, raw, side, matched.shape) if raw.dtype != np.uint8 else matched
            messages[f"{side}/image_rect"] = array_to_image(types, side_header, mono)
        if raw is not None and raw.ndim == 3 and f"{side}/image_rect_color" in wanted:
            colour = result.left_rect_color if side == "left" else None
            colour = colour if colour is not None else _rectified(frame, raw, side, matched.shape)
            messages[f"{side}/image_rect_color"] = array_to_image(types, side_header, colour)
    return messages


def _right_header(types: MessageTypes, frame: StereoFrame) -> Any:
    """The frame's stamp (a VO node pairs the two images by it exactly) with the right camera's frame_id."""
    right = frame.right_header if frame.right_header is not None else frame.header
    return make_header(types, frame.stamp_ns, str(right.frame_id))


def _rectified(frame: StereoFrame, raw: np.ndarray, side: str, shape: tuple[int, ...]) -> np.ndarray:
    """A rectified output the matcher did not need (the right colour image, a 16-bit camera's own values),
    built only when someone wants it."""
    return rectified_output(raw, frame.camera, side, rectified=frame.rectified, shape=shape)


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
    temporal filter's history and odometry state (touched only where frames are in stamp order:
    `filtered_disparity`)."""

    def __init__(self) -> None:
        self.temporal = TemporalFilter()
        self.odometry = OdometryState()
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
    too_near: np.ndarray | None = None  # nearer than the disparity range can see (near_points)
    nearest_depth: float = 0.0  # metres: the nearest depth the disparity range can see
    glare: np.ndarray | None = None  # the left image's saturated textureless area (core/saturation.py)


def result_geometry(pipeline: StereoPipeline, frame: StereoFrame, result: StereoResult) -> Geometry:
    """Depth of a `match` result, its disparity as matched."""
    assert result.camera is not None
    image = result.left_rect_color if result.left_rect_color is not None else result.left_rect
    return disparity_geometry(pipeline, frame, result.camera, result.disparity, image, result.too_near, result.glare)


def disparity_geometry(
    pipeline: StereoPipeline,
    frame: StereoFrame,
    camera: StereoCamera,
    disparity: np.ndarray,
    image: np.ndarray,
    too_near: np.ndarray | None = None,
    glare: np.ndarray | None = None,
) -> Geometry:
    """Depth of a frame's disparity (not offset-adjusted, at the size of `camera`); the pixels matched at
    the smallest disparity searched are marked for points2_clearing, and so is the glare they hold back;
    those too near for the range for `near_points`."""
    depth = disparity_to_depth(disparity, camera)
    params = pipeline.params
    step = 1 if params.downsample_output == "processed" else params.downsample  # one matcher step, output px
    with np.errstate(invalid="ignore"):  # NaN: not matched
        saturated = disparity < np.float32(output_params(params).min_disparity + step)
    nearest = nearest_matchable_depth(params, camera)
    rays = pipeline.rays_for(camera)
    return Geometry(depth, camera, rays, image, frame.camera, saturated, too_near, nearest, glare)


def nearest_matchable_depth(params: StereoParams, camera: StereoCamera) -> float:
    """Metres: the depth of the largest disparity searched (NaN where the calibration gives none)."""
    top = np.array([[nearest_disparity(params)]], np.float32)
    return float(disparity_to_depth(top, camera)[0, 0]) if camera.no_depth_reason is None else float("nan")


def range_limited_depth(geometry: Geometry, options: OutputOptions, masks: RectifiedMasks) -> np.ndarray:
    """points2's depth with `near_points: range_limit`: each too-near pixel at the nearest depth the range
    can see, unless the mask or min_depth holds it back (the geometry's depth is already limited)."""
    depth = geometry.depth
    near = geometry.too_near
    if near is None or not near.any() or not options.min_depth <= geometry.nearest_depth:
        return depth
    if options.mask_image:
        near = near & masks.get(options.mask_image, geometry.raw_camera, depth.shape)
    depth = depth.copy()
    depth[near] = np.float32(geometry.nearest_depth)
    return depth


def clearing_depth(geometry: Geometry, options: OutputOptions, masks: RectifiedMasks) -> np.ndarray:
    """The depth of points2_clearing (NaN elsewhere): pixels matched beyond max_depth or at the smallest
    disparity searched (as far as the matcher sees, or farther: their depth may be infinite), each at
    its depth clamped to clearing_max_depth. Such pixels never reach depth or points2 when beyond
    max_depth; the mask and min_depth still hold them back, and so does glare: white without texture, a
    matcher's disparity there is arbitrary (SGBM puts 2,700-3,600 pixels of each bundled EuRoC frame, a
    room, at the smallest disparity, more than half of them in or beside glare), and a clearing ray from
    one would clear real obstacles along it. Call before `limited_depth`."""
    depth = geometry.depth
    with np.errstate(invalid="ignore"):
        far = depth > np.float32(options.max_depth) if options.max_depth > 0 else np.zeros(depth.shape, bool)
        if geometry.at_min_disparity is not None:
            far |= geometry.at_min_disparity
        if options.min_depth > 0:
            far &= ~(depth < np.float32(options.min_depth))
    if geometry.glare is not None:
        far &= ~geometry.glare
    if options.mask_image:
        far &= masks.get(options.mask_image, geometry.raw_camera, depth.shape)
    clearing = np.full(depth.shape, np.nan, np.float32)
    clearing[far] = np.fmin(depth[far], np.float32(options.clearing_max_depth))  # fmin: infinite (NaN) -> the limit
    return clearing


def limited_depth(geometry: Geometry, options: OutputOptions, masks: RectifiedMasks) -> np.ndarray:
    """min_depth, max_depth and mask_image: the depth without the pixels they exclude (NaN), so neither
    depth nor points2 has them; the disparity stays as matched. The geometry's own depth is kept."""
    depth = geometry.depth
    if not (options.min_depth > 0 or options.max_depth > 0 or options.mask_image):
        return depth
    depth = depth.copy()
    with np.errstate(invalid="ignore"):
        if options.min_depth > 0:
            depth[depth < np.float32(options.min_depth)] = np.nan
        if options.max_depth > 0:
            depth[depth > np.float32(options.max_depth)] = np.nan
    if options.mask_image:
        depth[~masks.get(options.mask_image, geometry.raw_camera, depth.shape)] = np.nan
    return depth


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
    and the mask applied (`limited_depth`). An organized points2 has its x, y, z computed straight into
    the message.

    `state`: the caller's own for this stream; its cloud buffer is reused frame to frame, so hand the
    cloud on (publish, write) before the next call.
    """
    clearing = clearing_depth(geometry, options, state.masks) if "points2_clearing" in wanted else None
    geometry = geometry._replace(depth=limited_depth(geometry, options, state.masks))
    cloud = decimated(geometry, options.points_decimation)
    if "points2" in wanted and options.near_points == "range_limit":
        cloud = decimated(
            geometry._replace(depth=range_limited_depth(geometry, options, state.masks)), options.points_decimation
        )
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
        color = cloud.image if options.use_color else None
        messages["points2"] = depth_to_cloud(
            types,
            header,
            cloud.depth,
            cloud.rays,
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
            decimated(geometry._replace(depth=clearing), options.points_decimation).depth,
            cloud.rays,
            avoid_padding=options.avoid_point_cloud_padding,
            buffer=state.clearing_buffer,
            organized=False,
        )
    return messages


def decimated(geometry: Geometry, step: int) -> Geometry:
    """The geometry of every `step`th row and column (points_decimation): each kept pixel's own depth,
    ray and colour, bit for bit those of the full-size cloud's point there."""
    if step == 1:
        return geometry
    rays = Rays(x=np.ascontiguousarray(geometry.rays.x[:, ::step]), y=np.ascontiguousarray(geometry.rays.y[::step]))
    return geometry._replace(
        depth=np.ascontiguousarray(geometry.depth[::step, ::step]),
        rays=rays,
        image=np.ascontiguousarray(geometry.image[::step, ::step]),
    )
