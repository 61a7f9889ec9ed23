"""Depth registered to a colour camera (`rgb_in_left` set): the colour stream paired with the stereo frames
by stamp, and the messages of each pair, depth_image_proc's names.

- `depth_registered/image_rect`: the frame's depth (depth limits, mask, temporal filter and confidence
  applied) seen from the colour camera (core/registration.py), at its resolution, in its undistorted
  model; 32FC1 metres or 16UC1 millimetres as `depth_encoding`;
- `depth_registered/camera_info`: that model (K = P's 3x3, D = 0, R = I);
- `rgb/image_rect_color`: the colour image undistorted into it;
- `depth_registered/points`: an organized XYZRGB cloud in the colour camera's frame.

All four carry the colour image's stamp and frame_id. depth_image_proc's `register` differs: it stamps
with the depth image's stamp by default and passes the colour camera_info through verbatim (with its
distortion, which its registered image no longer has).

A colour image pairs with the stereo frame nearest in stamp within `rgb_sync_tolerance_seconds`
(nearest_sync.py); the stereo outputs never wait for it. A frame hands its depth over once its cloud job
ran (`add_depth`, in stamp order), which returns the pairs that became certain: the colour image just
after a frame may wait for the next frame.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Collection
from typing import Any, NamedTuple

import cv2
import numpy as np

from stereo_depth.core.camera import CameraInfo, build_rectification_maps, check_camera_info, needs_rectification
from stereo_depth.core.camera import rectified_input as rectified_colour
from stereo_depth.core.registration import PinholeModel, RigidMotion, left_rectified_to_colour, register_depth
from stereo_depth.errors import CalibrationError, ImageError, ParameterError
from stereo_depth.frames.decode import decode_image, named_errors
from stereo_depth.frames.outputs import Geometry, depth_pixels
from stereo_depth.messages import (
    MessageBuffer,
    MessageTypes,
    array_to_image,
    camera_info_from_msg,
    camera_info_to_msg,
    depth_to_cloud,
    make_header,
    stamp_to_ns,
)
from stereo_depth.nearest_sync import NearestPairing, PairingCounters
from stereo_depth.options import OutputOptions

REGISTERED_OUTPUTS = (
    "depth_registered/image_rect",
    "depth_registered/camera_info",
    "rgb/image_rect_color",
    "depth_registered/points",
)
COLOUR_INPUTS = ("rgb/image_raw", "rgb/camera_info")  # relative to the node's namespace


class ColourNames(NamedTuple):
    """What errors call the colour inputs: their topics live and offline."""

    image: str = "rgb/image_raw"
    info: str = "rgb/camera_info"


COLOUR_NAMES = ColourNames()


class ColourInput(NamedTuple):
    """One colour image with its camera_info (messages of either flavour; the image may be compressed)."""

    stamp_ns: int
    image: Any
    info: Any


class FrameDepth(NamedTuple):
    """What a stereo frame leaves for registration: its depth as depth and points2 carry it."""

    geometry: Geometry  # depth limited, at the output size, in the left rectified frame
    output: OutputOptions  # the frame's options (depth_encoding, rgb_in_left, ...)


def unset_pose_line(names: Collection[str]) -> str:
    """Why a registered output gives nothing: its pose is not set (names: the outputs asked for)."""
    return (
        f"{', '.join(names)} need the colour camera's pose: set rgb_in_left to [x, y, z, qx, qy, qz, qw], its "
        "optical frame in the left camera's optical frame"
    )


def check_registered_outputs(wanted: Collection[str], output: OutputOptions) -> None:
    """ParameterError when a registered output is asked for while rgb_in_left is unset."""
    asked = [name for name in REGISTERED_OUTPUTS if name in wanted]
    if asked and not output.rgb_in_left.is_set:
        raise ParameterError(unset_pose_line(asked))


class RegisteredJob:
    """One colour image and the depth of the stereo frame it paired with: run once, on any thread."""

    def __init__(self, registration: Registration, depth: FrameDepth, colour: ColourInput) -> None:
        self._registration, self.depth, self.colour = registration, depth, colour

    @property
    def stamp_ns(self) -> int:
        return self.colour.stamp_ns

    def run(self, wanted: Collection[str]) -> tuple[dict[str, Any], float]:
        """The messages in `wanted` (of REGISTERED_OUTPUTS) and the time they took, ms."""
        start = time.perf_counter()
        registration, output = self._registration, self.depth.output
        names = registration.names
        with named_errors(names.info):
            info = colour_calibration(self.colour.info)
        with named_errors(names.image):
            image = decode_image(self.colour.image, output.max_image_pixels)
        if image.shape[:2] != (info.height, info.width):
            msg = (
                f"{names.image} is {image.shape[1]}x{image.shape[0]} but {names.info} says {info.width}x{info.height}; "
                "publish the calibration of this colour camera mode"
            )
            raise ImageError(msg)
        header = make_header(registration.types, self.colour.stamp_ns, str(self.colour.image.header.frame_id))
        model = PinholeModel(info.width, info.height, *(float(v) for v in info.p[[0, 1, 0, 1], [0, 1, 2, 2]]))
        messages: dict[str, Any] = {}
        if "rgb/image_rect_color" in wanted or "depth_registered/points" in wanted:
            image = registration.undistorted(image, info)
        if "rgb/image_rect_color" in wanted:
            messages["rgb/image_rect_color"] = array_to_image(registration.types, header, image)
        if "depth_registered/camera_info" in wanted:
            messages["depth_registered/camera_info"] = camera_info_to_msg(
                registration.types, header, undistorted_model(info, str(header.frame_id))
            )
        if not {"depth_registered/image_rect", "depth_registered/points"} & set(wanted):
            return messages, (time.perf_counter() - start) * 1000.0
        geometry = self.depth.geometry
        motion = registration.motion(output, geometry, info)
        depth = register_depth(geometry.depth, geometry.rays, motion, model)
        if "depth_registered/image_rect" in wanted:
            pixels = depth_pixels(depth, output.depth_encoding)
            messages["depth_registered/image_rect"] = array_to_image(
                registration.types, header, pixels, output.depth_encoding
            )
        if "depth_registered/points" in wanted:
            colour = image if output.use_color and image.dtype == np.uint8 else None
            messages["depth_registered/points"] = depth_to_cloud(
                registration.types,
                header,
                depth,
                model.rays(),
                colour,
                avoid_padding=output.avoid_point_cloud_padding,
                buffer=registration.cloud_buffer,
                organized=True,
            )
        return messages, (time.perf_counter() - start) * 1000.0


def colour_calibration(msg: Any) -> CameraInfo:
    """A colour camera_info as registration uses it: a rectified one (D = 0, only P set) is accepted."""
    info = rectified_colour(camera_info_from_msg(msg))
    if not info.p.any():  # no P (a driver that fills K only): the undistorted model is K
        info = dataclasses.replace(info, p=np.hstack([info.k, np.zeros((3, 1))]))
    if info.p[0, 0] <= 0 or info.p[1, 1] <= 0:
        msg_text = (
            f"no focal length (K = {info.k.ravel().tolist()}, P[0,0] = {info.p[0, 0]}): the colour camera is "
            "uncalibrated; calibrate it (camera_calibration) and publish its camera_info"
        )
        raise CalibrationError(msg_text)
    check_camera_info(info, "colour")
    return info


def undistorted_model(info: CameraInfo, frame_id: str) -> CameraInfo:
    """The colour camera after undistortion: K = P's 3x3, D = 0, R = I, P = [K | 0]."""
    k = info.p[:, :3].copy()
    return CameraInfo.from_values(
        info.width, info.height, k, np.zeros(5), np.eye(3), np.hstack([k, np.zeros((3, 1))]), "plumb_bob", frame_id
    )


class Registration:
    """One stream's registration state: the colour images waiting for their frame, the pairing, and what
    is built once per calibration (undistortion maps, the transform). Thread-safe: the colour images may
    come on another thread than the frames."""

    def __init__(self, types: MessageTypes, names: ColourNames = COLOUR_NAMES) -> None:
        self.types, self.names = types, names
        self.cloud_buffer = MessageBuffer()
        self._lock = threading.Lock()
        self._pairing: NearestPairing[FrameDepth, ColourInput] = NearestPairing(0)
        self._maps: tuple[tuple[object, ...], tuple[np.ndarray, np.ndarray]] | None = None
        self._motion: tuple[tuple[object, ...], RigidMotion] | None = None

    @property
    def counters(self) -> PairingCounters:
        return self._pairing.counters

    def add_colour(self, image: Any, info: Any) -> None:
        """A colour image and its camera_info, kept until a frame decides what it pairs with."""
        with self._lock:
            self._pairing.add_extra(
                stamp_to_ns(image.header.stamp), ColourInput(stamp_to_ns(image.header.stamp), image, info)
            )

    def add_depth(self, stamp_ns: int, depth: FrameDepth) -> list[RegisteredJob]:
        """A frame's depth (call in stamp order); returns the colour images it decided, paired."""
        with self._lock:
            self._pairing.tolerance_ns = round(depth.output.rgb_sync_tolerance_seconds * 1e9)
            pairs = self._pairing.add_primary(stamp_ns, depth)
        return [RegisteredJob(self, pair.primary, pair.extra) for pair in pairs]

    def flush(self) -> list[RegisteredJob]:
        """The end of the input (a bag's, or a pause): the colour images still waiting, paired."""
        with self._lock:
            pairs = self._pairing.flush()
        return [RegisteredJob(self, pair.primary, pair.extra) for pair in pairs]

    def undistorted(self, image: np.ndarray, info: CameraInfo) -> np.ndarray:
        """The colour image in its undistorted model (as it is when it has no distortion)."""
        if not needs_rectification(info):
            return image
        key = info.key()
        with self._lock:
            if self._maps is None or self._maps[0] != key:
                self._maps = (key, build_rectification_maps(info))
            map1, map2 = self._maps[1]
        return cv2.remap(image, map1, map2, cv2.INTER_LINEAR)

    def motion(self, output: OutputOptions, geometry: Geometry, info: CameraInfo) -> RigidMotion:
        """From the depth's frame (left rectified) to the colour camera's undistorted one."""
        key = (output.rgb_in_left, geometry.raw_camera.left.key(), info.key())
        with self._lock:
            if self._motion is None or self._motion[0] != key:
                motion = left_rectified_to_colour(output.rgb_in_left, geometry.raw_camera.left.r, info.r)
                self._motion = (key, motion)
            return self._motion[1]
