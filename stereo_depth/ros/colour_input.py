"""A node's colour camera inputs (rgb_in_left set): rgb/image_raw (or its /compressed, `rgb_image_transport`)
and rgb/camera_info, subscribed from activation to deactivation whenever the pose is set, paired with each
other by stamp as the stereo inputs are (input_pairing.py), and each pair handed on as it completes.

They are paired with the stereo frames later, by stamp only, after the stereo outputs went out
(frames/registered.py): a colour camera that stops pauses the registered outputs alone, and diagnostics
report it as a silent input and count the frames without a colour image.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

from stereo_depth.frames.registered import COLOUR_INPUTS
from stereo_depth.options import NodeOptions
from stereo_depth.ros.diagnostics import NodeDiagnostics
from stereo_depth.ros.input_pairing import InputPairing, InputSpec, InputTopics
from stereo_depth.ros.problems import ProblemLog
from stereo_depth.ros.qos import AdaptiveSubscription

COLOUR_SPEC = InputSpec(((COLOUR_INPUTS[0], Image), (COLOUR_INPUTS[1], CameraInfo)), ((1, 0),), (0,), ())


def colour_options(options: NodeOptions) -> NodeOptions:
    """The node's input options with the colour camera's own transport."""
    return dataclasses.replace(options, image_transport=options.rgb_image_transport)


class ColourInputs:
    """Resolved at configure; subscribed at `open` (activate), released at `close`."""

    def __init__(self, node: Node, options: NodeOptions) -> None:
        self._node = node
        self._topics = InputTopics(node, COLOUR_SPEC, colour_options(options))
        self.names = self._topics.names
        self._pairing: InputPairing | None = None

    def open(
        self,
        options: NodeOptions,
        diagnostics: NodeDiagnostics,
        problems: ProblemLog,
        add_colour: Callable[[Any, Any], None],
        report_bug: Callable[[Exception], None],
    ) -> None:
        def submit(_stamp_ns: int, messages: tuple[Any, ...], _received_s: float) -> None:
            add_colour(*messages)

        self._pairing = InputPairing(
            self._node, COLOUR_SPEC, self._topics, colour_options(options), diagnostics, problems, submit, report_bug
        )

    def close(self) -> None:
        if self._pairing is not None:
            self._pairing.close()
            self._pairing = None

    @property
    def subscriptions(self) -> list[AdaptiveSubscription]:
        return self._pairing.subscriptions if self._pairing is not None else []

    def flush_when_idle(self) -> None:
        if self._pairing is not None:
            self._pairing.flush_when_idle()

    def options_changed(self, old: NodeOptions, new: NodeOptions) -> None:
        if self._pairing is not None:
            self._pairing.options_changed(colour_options(old), colour_options(new))
