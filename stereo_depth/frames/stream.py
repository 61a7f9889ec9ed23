"""FrameStream: one stream of frames from input messages to output messages, returned to the caller.

stereo_node, disparity_node, point_cloud_node, the lifecycle node and `stereo-depth process` each hold one
and publish or write what it returns, so live and offline outputs agree by construction. Per frame:

- `match(inputs, wanted)`: decode, match, then in stamp order the temporal filter and the image messages
  (left/image_rect(_color), disparity, confidence); returns them with a cloud job, or None when no cloud
  output is due, and whether the calibration changed. A node matching several frames at once calls its
  two halves, `matched` (any thread) and `outputs` (in input order), instead.
- with `left_in_base` set, the temporal filter moves its history by the odometry the caller feeds to
  `odometry` (frames/odometry.py); a frame where it stopped or jumped says so (`odometry_event`).
- `CloudJob.run()`: depth, the depth limits and mask, and the messages of depth (depth, its camera_info and
  compressedDepth, points2, points2_clearing); a node runs it on its second thread. With `rgb_in_left` set
  it hands the frame's depth to `registration` (frames/registered.py) and returns the registered jobs
  that became due: colour images paired with a frame, each to run once.

The stages run in this one order in this one place; each returns its own output (the core's StereoResult
stays as the matcher gave it). Nothing here calls back into its caller.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Collection
from typing import Any, NamedTuple

import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.geometry import disparity_to_depth
from stereo_depth.core.odometry import OdometryTrack
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.errors import ImageError, StereoDepthError
from stereo_depth.frames.decode import INPUT_NAMES, InputNames, StereoFrame, decode_frame, match_frame, named_errors
from stereo_depth.frames.odometry import FrameOdometry
from stereo_depth.frames.outputs import (
    GEOMETRY_OUTPUTS,
    Geometry,
    OutputState,
    disparity_geometry,
    filtered_disparity,
    geometry_outputs,
    image_outputs,
    limited_depth,
)
from stereo_depth.frames.registered import COLOUR_NAMES, ColourNames, FrameDepth, RegisteredJob, Registration
from stereo_depth.messages import MessageTypes, disparity_from_msg
from stereo_depth.options import OutputOptions
from stereo_depth.sync import StereoSet


class Matched(NamedTuple):
    """A frame decoded and matched, with the options and parameters it was read and matched with."""

    frame: StereoFrame
    result: StereoResult
    output: OutputOptions
    params: StereoParams
    decode_ms: float


class CloudOutputs(NamedTuple):
    """What a cloud job gives: the messages by output name, the stage times ("depth", "points", ms) and,
    when the job was asked for it, the geometry they were built from (its depth limited as theirs)."""

    messages: dict[str, Any]
    stage_ms: dict[str, float]
    geometry: Geometry | None = None
    registered: tuple[RegisteredJob, ...] = ()  # colour images this frame's depth decided (rgb_in_left)


class CloudJob:
    """The depth and cloud outputs of one frame, to run once on any thread (in stamp order with the other
    frames' jobs: the stream's cloud buffers are reused)."""

    def __init__(
        self,
        stream: FrameStream,
        frame: StereoFrame,
        camera: StereoCamera,
        disparity: np.ndarray,
        image: np.ndarray,
        output: OutputOptions,
        wanted: Collection[str],
        *,
        offset_adjusted: bool = False,
        with_geometry: bool = False,
        too_near: np.ndarray | None = None,
        glare: np.ndarray | None = None,
    ) -> None:
        self._stream, self.frame, self._camera = stream, frame, camera
        self._too_near, self._glare = too_near, glare
        self._disparity, self._image, self._output = disparity, image, output
        self.wanted, self._offset_adjusted, self._with_geometry = frozenset(wanted), offset_adjusted, with_geometry

    def run(self) -> CloudOutputs:
        stream, camera = self._stream, self._camera
        start = time.perf_counter()
        if self._offset_adjusted:  # a DisparityImage's (point_cloud_node): no search range known
            depth = disparity_to_depth(self._disparity, camera, offset_adjusted=True)
            geometry = Geometry(depth, camera, stream.pipeline.rays_for(camera), self._image, camera)
        else:
            geometry = disparity_geometry(
                stream.pipeline, self.frame, camera, self._disparity, self._image, self._too_near, self._glare
            )
        depth_ms = (time.perf_counter() - start) * 1000.0
        start = time.perf_counter()
        messages = geometry_outputs(stream.types, self.frame.header, geometry, self._output, self.wanted, stream.state)
        points_ms = (time.perf_counter() - start) * 1000.0
        stage_ms = {"depth": depth_ms, "points": points_ms}
        registering = self._output.rgb_in_left.is_set and not self._offset_adjusted
        if not (self._with_geometry or registering):
            return CloudOutputs(messages, stage_ms)
        limited = geometry._replace(depth=limited_depth(geometry, self._output, stream.state.masks))
        registered: tuple[RegisteredJob, ...] = ()
        if registering:
            registered = tuple(stream.registration.add_depth(self.frame.stamp_ns, FrameDepth(limited, self._output)))
        return CloudOutputs(messages, stage_ms, limited if self._with_geometry else None, registered)


class FrameOutputs(NamedTuple):
    """One frame's image messages by output name, its cloud job (None: no cloud output due), whether its
    calibration differs from the last frame's the stream returned, and what they were built from."""

    frame: StereoFrame
    result: StereoResult  # the matcher's, as it gave it
    disparity: np.ndarray  # the frame's, after the temporal filter: what disparity, depth and points2 carry
    images: dict[str, Any]
    cloud: CloudJob | None
    calibration_changed: bool
    stage_ms: dict[str, float]  # the matcher's stage times, and "temporal" when it ran
    odometry_event: str | None = None  # the odometry stopped or jumped at this frame (frames/odometry.py)


class DisparityOutputs(NamedTuple):
    """A disparity message's frame (point_cloud_node): its cloud job (None: no depth or not due)."""

    frame: StereoFrame
    cloud: CloudJob | None
    calibration_changed: bool


class FrameStream:
    """The pipeline, the options and the per-stream state (temporal filter, mask, message buffers, cloud
    rate) of one stream of frames. `names` name the inputs in errors (the topics, live and offline);
    `rectified`: the inputs are rectified images already."""

    def __init__(
        self,
        types: MessageTypes,
        params: StereoParams | None = None,
        output: OutputOptions | None = None,
        *,
        rectified: bool = False,
        names: InputNames = INPUT_NAMES,
        colour_names: ColourNames = COLOUR_NAMES,
    ) -> None:
        self.types, self.rectified, self.names = types, rectified, names
        self.registration = Registration(types, colour_names)  # fed colour images by the caller (rgb_in_left)
        self.odometry = OdometryTrack()  # fed odometry messages by the caller (left_in_base)
        self.pipeline = StereoPipeline(params)
        self.output = output or OutputOptions()
        self.state = OutputState()
        self._returned: StereoCamera | None = None  # the calibration of the last frame returned
        self._lock = threading.Lock()

    def use(self, params: StereoParams | None, output: OutputOptions) -> None:
        """New parameters and options (a node's parameter change): frames from here on use them."""
        if params is not None and self.pipeline.params is not params:
            self.pipeline.set_params(params)
        self.output = output

    def match(self, inputs: StereoSet, wanted: Collection[str], *, with_geometry: bool = False) -> FrameOutputs:
        """`matched`, then `outputs`: a frame at a time."""
        return self.outputs(self.matched(inputs), wanted, with_geometry=with_geometry)

    def matched(self, inputs: StereoSet) -> Matched:
        """Decode and match (rectify, match, filter); safe on several threads at once."""
        output, params = self.output, self.pipeline.params
        start = time.perf_counter()
        frame = decode_frame(inputs, self.pipeline, output, rectified=self.rectified, names=self.names)
        decode_ms = (time.perf_counter() - start) * 1000.0
        return Matched(frame, match_frame(self.pipeline, frame, self.names), output, params, decode_ms)

    def outputs(self, matched: Matched, wanted: Collection[str], *, with_geometry: bool = False) -> FrameOutputs:
        """The temporal filter, the image messages in `wanted` and the cloud job of those due; call in stamp
        order. `with_geometry`: a cloud job even when no cloud output is due (a PLY needs the geometry)."""
        frame, result, output = matched.frame, matched.result, matched.output
        stage_ms = dict(result.timings_ms)
        start = time.perf_counter()
        odometry = self._odometry(matched)
        disparity = filtered_disparity(self.state.temporal, frame, result, matched.params, odometry.motion)
        if matched.params.temporal_filter:
            stage_ms["temporal"] = (time.perf_counter() - start) * 1000.0
        images = image_outputs(
            self.types, frame, result, disparity, matched.params, wanted, self.state.disparity_buffer
        )
        cloud = None
        if frame.camera.no_depth_reason is None:  # no baseline: disparity only (the caller warns once)
            due = self.state.cloud_rate.wanted([n for n in GEOMETRY_OUTPUTS if n in wanted], frame.stamp_ns, output)
            if due or with_geometry or output.rgb_in_left.is_set:
                assert result.camera is not None  # match_frame passes the frame's camera
                image = result.left_rect_color if result.left_rect_color is not None else result.left_rect
                cloud = CloudJob(
                    self,
                    frame,
                    result.camera,
                    disparity,
                    image,
                    output,
                    due,
                    with_geometry=with_geometry,
                    too_near=result.too_near,
                    glare=result.glare,
                )
        changed = self._calibration_changed(frame.camera)
        return FrameOutputs(frame, result, disparity, images, cloud, changed, stage_ms, odometry.event)

    def lead_in(self, inputs: StereoSet) -> None:
        """A frame before a shard's own: matched and fed to the temporal filter as one pass would, no
        outputs. A frame that one pass skips is skipped here too."""
        try:
            matched = self.matched(inputs)
        except StereoDepthError:
            return
        odometry = self._odometry(matched)
        filtered_disparity(self.state.temporal, matched.frame, matched.result, matched.params, odometry.motion)

    def _odometry(self, matched: Matched) -> FrameOdometry:
        """Where the camera was at this frame (`left_in_base` set), from the odometry fed to `odometry`."""
        return self.state.odometry.frame(self.odometry, matched.frame, matched.result, matched.params, matched.output)

    def disparity_cloud(self, inputs: StereoSet, disparity_msg: Any, disparity_name: str) -> DisparityOutputs:
        """The cloud job of a DisparityImage (offset-adjusted, its rectified left image as colour in
        `inputs`, no right image), if points_max_rate finds it due and the calibration has a baseline."""
        output = self.output
        frame = decode_frame(inputs, self.pipeline, output, rectified=True, names=self.names)
        camera = frame.camera
        with named_errors(disparity_name):
            disparity = disparity_from_msg(disparity_msg)
        if disparity.shape != (camera.height, camera.width):
            msg = (
                f"{disparity_name}: {disparity.shape[1]}x{disparity.shape[0]} but camera_info says "
                f"{camera.width}x{camera.height}; remap the topics of one camera together"
            )
            raise ImageError(msg)
        cloud = None
        if camera.no_depth_reason is None and self.state.cloud_rate.due(frame.stamp_ns, output.points_max_rate):
            cloud = CloudJob(self, frame, camera, disparity, frame.left, output, ("points2",), offset_adjusted=True)
        return DisparityOutputs(frame, cloud, self._calibration_changed(camera))

    def _calibration_changed(self, camera: StereoCamera) -> bool:
        """Whether `camera` is another calibration than that of the last frame returned (the pipeline builds
        a new StereoCamera, maps and all, for each calibration it is given)."""
        with self._lock:
            changed = camera is not self._returned
            self._returned = camera
        return changed
