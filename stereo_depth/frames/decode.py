"""A frame's inputs decoded: images and calibration checked, every error naming the input it is about."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, NamedTuple, TypeVar

import numpy as np

from stereo_depth.core.camera import StereoCamera, rectified_input, with_baseline
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.errors import CalibrationError, ImageError, StereoDepthError
from stereo_depth.messages import (
    DEFAULT_MAX_PIXELS,
    camera_info_from_msg,
    compressed_to_pipeline,
    image_to_pipeline,
    stamp_to_ns,
)
from stereo_depth.options import OutputOptions
from stereo_depth.sync import StereoSet


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
    right_header: Any = None  # the right image's header (its frame_id goes on right/image_rect)


@contextmanager
def named_errors(name: str) -> Iterator[None]:
    """Our errors raised inside, with `name` (a topic) in front."""
    try:
        yield
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
    with named_errors(names[0]):
        left = camera_info_from_msg(left_info)
    with named_errors(names[1]):
        right = camera_info_from_msg(right_info)
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
    with named_errors(names.left_image):
        left = decode_image(inputs.left_image, options.max_image_pixels)
    (lh, lw), images, right = left.shape[:2], f"{names.left_image} is", None
    if inputs.right_image is not None:
        with named_errors(names.right_image):
            right = decode_image(inputs.right_image, options.max_image_pixels)
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
    right_header = inputs.right_image.header if inputs.right_image is not None else None
    return StereoFrame(stamp_to_ns(header.stamp), header, left, right, camera, rectified, right_header)


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
