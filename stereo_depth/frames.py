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
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, TypeVar

import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.geometry import Rays
from stereo_depth.core.matching import valid_window
from stereo_depth.core.params import StereoParams, _spec, coerce
from stereo_depth.core.pipeline import StereoPipeline, StereoResult, output_params
from stereo_depth.errors import CalibrationError, ImageError, ParameterError, StereoDepthError
from stereo_depth.messages import (
    DEFAULT_MAX_PIXELS,
    CloudBuffer,
    MessageTypes,
    array_to_image,
    camera_info_from_msg,
    compressed_to_pipeline,
    depth_to_cloud,
    disparity_to_msg,
    image_to_pipeline,
    stamp_to_ns,
)

T = TypeVar("T")

# Output names, relative to the node's namespace (the topics stereo_node publishes).
IMAGE_OUTPUTS = ("left/image_rect", "left/image_rect_color", "disparity", "confidence")
GEOMETRY_OUTPUTS = ("depth", "points2")
OUTPUTS = (*IMAGE_OUTPUTS, *GEOMETRY_OUTPUTS)

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

    def validate(self) -> OutputOptions:
        for f in dataclasses.fields(self):
            spec, value = f.metadata, getattr(self, f.name)
            if spec.get("min") is not None and not spec["min"] <= value <= spec["max"]:
                msg = f"{f.name} {value} is outside [{spec['min']}, {spec['max']}]"
                raise ParameterError(msg)
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


# ---------------------------------------------------------------- match outputs


def disparity_message(
    types: MessageTypes, header: Any, disparity: np.ndarray, camera: StereoCamera, params: StereoParams
) -> Any:
    """DisparityImage with the matcher's real valid window and resolution (1/16 px per downsample step)."""
    params = output_params(params)  # the disparity's own size and range (downsample_output)
    height, width = disparity.shape
    return disparity_to_msg(
        types,
        header,
        disparity,
        camera,
        params.min_disparity,
        params.disparity_range,
        valid_window(width, height, params),
        delta_d=params.downsample / 16.0,
    )


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


class Geometry(NamedTuple):
    """What depth and points2 are built from: one frame's depth with its calibration and colour."""

    depth: np.ndarray  # float32 metres, NaN invalid, at the output size
    camera: StereoCamera  # the calibration of that size
    rays: Rays
    image: np.ndarray  # rectified left, BGR or grey: the cloud's colour


def result_geometry(pipeline: StereoPipeline, result: StereoResult) -> Geometry:
    """Depth of a `match` result (`pipeline.add_geometry`; the points go straight into the cloud)."""
    assert result.camera is not None
    pipeline.add_geometry(result, want_points=False)
    assert result.depth is not None
    image = result.left_rect_color if result.left_rect_color is not None else result.left_rect
    return Geometry(result.depth, result.camera, pipeline.rays_for(result.camera), image)


def geometry_outputs(
    types: MessageTypes,
    header: Any,
    geometry: Geometry,
    options: OutputOptions,
    wanted: Collection[str],
    cloud_buffer: CloudBuffer | None = None,
) -> dict[str, Any]:
    """depth and points2 by output name, those in `wanted`. points2 is organized like
    stereo_image_proc's, its x, y, z computed straight into the message's buffer.

    `cloud_buffer`: the caller's own, reused frame to frame; hand the cloud on (publish, write)
    before the next call reuses it.
    """
    messages: dict[str, Any] = {}
    if "depth" in wanted:
        messages["depth"] = array_to_image(types, header, geometry.depth, "32FC1")
    if "points2" in wanted:
        color = geometry.image if options.use_color else None
        messages["points2"] = depth_to_cloud(
            types,
            header,
            geometry.depth,
            geometry.rays,
            color,
            avoid_padding=options.avoid_point_cloud_padding,
            buffer=cloud_buffer,
        )
    return messages
