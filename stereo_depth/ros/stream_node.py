"""The nodes that hold a FrameStream (the matching nodes, point_cloud_node): the stream, its publishers, and
what a frame's returned messages and calibration change become (publishing, diagnostics, one log line)."""

from __future__ import annotations

import time
from typing import Any, ClassVar

from stereo_depth.core.camera import StereoCamera
from stereo_depth.frames import FrameStream, InputNames
from stereo_depth.ros.node_base import StereoIONode, timed
from stereo_depth.ros.serialized_publish import publish
from stereo_depth.ros.types import RCLPY_SERIALIZED


class StreamNode(StereoIONode):
    """A subclass names its inputs, options and outputs; its stream exists from construction on and is
    built anew, with the node's parameters, at configure and released at cleanup."""

    RECTIFIED = False  # the image inputs are rectified already
    # which input each of InputNames' four is (None: there is none), for the errors and log lines naming them
    NAMED_INPUTS: ClassVar[tuple[int | None, int | None, int | None, int | None]] = (0, 1, 2, 3)

    def __init__(self, name: str, **kwargs: Any) -> None:
        # the stream of this node's parameters from configure on (which a plain node runs inside super().__init__)
        self.stream = FrameStream(RCLPY_SERIALIZED, rectified=self.RECTIFIED)
        self.configured = False
        self._calibrations = 0  # calibrations the frames came with since configure
        super().__init__(name, **kwargs)

    @property
    def input_names(self) -> InputNames:
        return InputNames(*("" if index is None else self.topics[index] for index in self.NAMED_INPUTS))

    def open_outputs(self) -> None:
        settings = self.parameters.settings
        self.stream = FrameStream(
            RCLPY_SERIALIZED, settings.stereo, settings.output, rectified=self.RECTIFIED, names=self.input_names
        )
        self.configured, self._calibrations = True, 0
        # the stream's buffers are reused frame to frame: publish() serializes first
        self._output_publishers = {name: self.declared_output(name) for name in self.output_names()}

    def output_names(self) -> list[str]:
        """The outputs this node publishes with its settings: all of OUTPUTS unless a subclass says less."""
        return [name for name, _ in self.OUTPUTS]

    def cleanup_io(self) -> None:
        super().cleanup_io()
        self.stream = FrameStream(RCLPY_SERIALIZED, rectified=self.RECTIFIED)  # maps, matchers, buffers released
        self.configured = False

    def publish_outputs(self, messages: dict[str, Any], stages: dict[str, float], received_s: float) -> None:
        """Publish each output, timed on its own ("publish points2" in diagnostics): a slow subscriber of
        one topic shows as that topic's time."""
        for name, message in messages.items():
            start = time.perf_counter()
            publish(self._output_publishers[name], message)
            timed(stages, f"publish {name}", start)
            self.published(name, received_s)

    def note_calibration(self, camera: StereoCamera) -> None:
        """Diagnostics and one log line when a frame came with a new calibration."""
        self._calibrations += 1
        self.diagnostics.calibrations_loaded(self._calibrations)
        names = self.stream.names
        self.problems.info(
            f"calibration {'changed' if self._calibrations > 1 else 'received'} (left = {names.left_info}, "
            f"right = {names.right_info}): {camera.width}x{camera.height}, fx {camera.fx:.1f} px, baseline "
            f"{camera.baseline:.4f} m; rectification maps rebuilt",
            key=("calibration", str(hash(camera.key()))),
        )
