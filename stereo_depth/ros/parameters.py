"""The nodes' ROS parameters: declared from the dataclasses, validated as a whole, applied atomically.

Processing parameters come from `StereoParams` (core); parameters that only make sense on a live node
(sync, QoS, outputs, point cloud layout) live in `NodeOptions` below. Both carry description and range
in their field metadata, so the descriptors shown by `ros2 param describe` and the checks agree.

Start-up order makes `-p profile:=X` work as documented: `profile` is read first, every processing
parameter is then declared with X's value as its default, and rclpy applies explicit `-p` /
`--params-file` values on top. stereo_image_proc's `stereo_algorithm` and `full_dp` are aliases: given
at start-up they set the default of `matcher` / `sgbm_mode`; set at run time they set those parameters.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from stereo_depth.core.matching import MATCHERS
from stereo_depth.core.params import COMPAT_ALIASES, PROFILES, StereoParams, translate_aliases
from stereo_depth.errors import ParameterError
from stereo_depth.messages import DEFAULT_MAX_PIXELS

RELIABILITY_CHOICES = ("auto", "reliable", "best_effort")
IMAGE_TRANSPORTS = ("raw", "compressed")
INTERPOLATIONS = {0: "nearest", 1: "linear", 2: "cubic", 3: "area", 4: "lanczos4"}


def _spec(description: str, lo: float | None = None, hi: float | None = None, step: float = 0) -> dict[str, Any]:
    return {"description": description, "min": lo, "max": hi, "step": step}


@dataclass(frozen=True)
class NodeOptions:
    """Node-only parameters; each node declares the subset it uses (see `*_OPTIONS`)."""

    queue_size: int = field(
        default=5, metadata=_spec("Messages kept per input while waiting for the rest of a set", 1, 100, 1)
    )
    approximate_sync: bool = field(
        default=False,
        metadata=_spec("Pair inputs whose stamps differ by up to approximate_sync_tolerance_seconds"),
    )
    approximate_sync_tolerance_seconds: float = field(
        default=0.0,
        metadata=_spec("Largest stamp difference inside one approximate set, s (0 = no limit)", 0.0, 10.0),
    )
    use_system_default_qos: bool = field(
        default=False,
        metadata=_spec("stereo_image_proc compatibility: true subscribes reliable when input_reliability is auto"),
    )
    input_reliability: str = field(
        default="auto",
        metadata=_spec("Subscription reliability: auto (follow the publishers, as rosbag2), reliable, best_effort"),
    )
    use_color: bool = field(default=True, metadata=_spec("Add PCL-style packed rgb to points2"))
    avoid_point_cloud_padding: bool = field(
        default=False, metadata=_spec("Pack points2 tightly (16-byte points) instead of stereo_image_proc's 32")
    )
    publish_rectified: bool = field(default=True, metadata=_spec("Publish left/image_rect(_color)"))
    publish_disparity: bool = field(default=True, metadata=_spec("Publish disparity (stereo_msgs/DisparityImage)"))
    publish_depth: bool = field(default=True, metadata=_spec("Publish depth (32FC1, metres, NaN invalid)"))
    publish_points: bool = field(default=True, metadata=_spec("Publish points2 (sensor_msgs/PointCloud2)"))
    publish_confidence: bool = field(
        default=True, metadata=_spec("Publish confidence (32FC1, 0..1) when the matcher gives one (census_sgm)")
    )
    calibration_check: bool = field(
        default=True,
        metadata=_spec("Check now and then that rectified rows still agree (report in diagnostics)"),
    )
    calibration_check_every_n_frames: int = field(
        default=30, metadata=_spec("Run the calibration check on one frame in this many", 1, 100000, 1)
    )
    max_waiting_frames: int = field(
        default=1,
        metadata=_spec(
            "Complete input sets kept while one is processed; one more drops the oldest (counted in "
            "diagnostics). 1: always the newest, lowest latency; more: no frame lost to a busy machine's hiccups",
            1,
            100,
            1,
        ),
    )
    matching_threads: int = field(
        default=1,
        metadata=_spec(
            "Frames matched at once, outputs kept in input order. 2 raises the rate of a matcher that leaves "
            "cores idle (census_sgm: 1.3-1.4x on 2 cores, bench/parallel_matching.py) at the cost of latency",
            1,
            4,
            1,
        ),
    )
    image_transport: str = field(
        default="raw",
        metadata=_spec(
            "Image inputs, read at start-up (stereo_image_proc's meaning): raw (sensor_msgs/Image) or "
            "compressed (<image topic>/compressed, sensor_msgs/CompressedImage, JPEG or PNG)"
        ),
    )
    left_camera_info_url: str = field(
        default="",
        metadata=_spec(
            "Left camera_info YAML, read at start-up (file:///path/left.yaml, as camera_info_manager); "
            "when set it replaces the left/camera_info topic"
        ),
    )
    right_camera_info_url: str = field(
        default="",
        metadata=_spec("Right camera_info YAML, as left_camera_info_url; replaces the right/camera_info topic"),
    )
    max_image_pixels: int = field(
        default=DEFAULT_MAX_PIXELS,
        metadata=_spec("Refuse input images with more pixels than this (protects memory)", 1, 1 << 28, 1),
    )
    interpolation: int = field(
        default=1,
        metadata=_spec("Rectification interpolation: 0 nearest, 1 linear, 2 cubic, 3 area, 4 lanczos4", 0, 4, 1),
    )

    def validate(self) -> NodeOptions:
        if self.input_reliability not in RELIABILITY_CHOICES:
            msg = f"input_reliability '{self.input_reliability}' must be one of {', '.join(RELIABILITY_CHOICES)}"
            raise ParameterError(msg)
        if self.image_transport not in IMAGE_TRANSPORTS:
            msg = f"image_transport '{self.image_transport}' must be one of {', '.join(IMAGE_TRANSPORTS)}"
            raise ParameterError(msg)
        return self

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


SYNC_OPTIONS = ("queue_size", "approximate_sync", "approximate_sync_tolerance_seconds")
INPUT_OPTIONS = (*SYNC_OPTIONS, "use_system_default_qos", "input_reliability", "max_waiting_frames", "max_image_pixels")
CLOUD_OPTIONS = ("use_color", "avoid_point_cloud_padding")
CAMERA_OPTIONS = ("image_transport", "left_camera_info_url", "right_camera_info_url")  # what the inputs are
STARTUP_OPTIONS = frozenset(CAMERA_OPTIONS)  # they choose the subscriptions: read-only once running


@dataclass(frozen=True)
class Settings:
    """One consistent set of values: what a frame is processed with (swapped as a whole)."""

    stereo: StereoParams | None
    options: NodeOptions


def _describe(f: dataclasses.Field[Any], *, read_only: bool = False) -> ParameterDescriptor:
    spec = f.metadata
    descriptor = ParameterDescriptor(description=spec["description"], read_only=read_only)
    if spec.get("min") is None:
        return descriptor
    lo, hi, step = spec["min"], spec["max"], spec["step"]
    descriptor.description += f" [{lo} .. {hi}" + (f", step {step}]" if step else "]")
    if f.type in ("int", int):
        descriptor.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=int(step))]
    else:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(lo), to_value=float(hi), step=float(step))
        ]
    return descriptor


def _alias_descriptor(name: str) -> ParameterDescriptor:
    text = {
        "stereo_algorithm": "stereo_image_proc alias: 0 sets matcher to bm, 1 to sgbm",
        "full_dp": "stereo_image_proc alias: true sets sgbm_mode to 1 (HH, full 8-path)",
    }[name]
    return ParameterDescriptor(description=text)


class NodeParameters:
    """Declares one node's parameters and keeps its `Settings` valid and current.

    `on_change` runs after a successful `ros2 param set` with the new Settings; the node swaps them in
    one assignment so a frame is processed with the old set or the new one, never a mix.
    """

    def __init__(
        self,
        node: Node,
        option_names: Sequence[str],
        *,
        with_stereo: bool,
        on_change: Callable[[Settings], None],
    ) -> None:
        self._node = node
        self._option_names = tuple(option_names)
        self._stereo_names: tuple[str, ...] = ()
        self._on_change = on_change
        if with_stereo:
            self._declare_stereo()
        options = {f.name: f for f in dataclasses.fields(NodeOptions)}
        for name in self._option_names:
            descriptor = _describe(options[name], read_only=name in STARTUP_OPTIONS)
            node.declare_parameter(name, getattr(NodeOptions(), name), descriptor)
        self.settings = self._build({})  # a bad start-up value raises ParameterError here
        node.add_pre_set_parameters_callback(self._expand_aliases)
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._apply)

    def _declare_stereo(self) -> None:
        node = self._node
        profile = node.declare_parameter(
            "profile",
            "default",
            ParameterDescriptor(
                description=f"Named set of defaults, read at start-up: {', '.join(PROFILES)}",
                read_only=True,
            ),
        ).value
        if profile not in PROFILES:
            msg = f"profile '{profile}' is unknown; choose one of {', '.join(PROFILES)}"
            raise ParameterError(msg)
        given = {}
        for alias in COMPAT_ALIASES:
            kind = Parameter.Type.INTEGER if alias == "stereo_algorithm" else Parameter.Type.BOOL
            value = node.declare_parameter(alias, kind, _alias_descriptor(alias)).value
            if value is not None:
                given[alias] = value
        defaults = {**PROFILES[profile], **translate_aliases(given)}
        base = StereoParams(**defaults)
        for f in dataclasses.fields(StereoParams):
            descriptor = _describe(f)
            if f.name == "matcher":
                descriptor.additional_constraints = f"one of: {', '.join(sorted(MATCHERS))}"
            node.declare_parameter(f.name, getattr(base, f.name), descriptor)
        self._stereo_names = tuple(f.name for f in dataclasses.fields(StereoParams))

    def _values(self, changes: dict[str, Any]) -> dict[str, Any]:
        names = (*self._stereo_names, *self._option_names)
        current = {name: self._node.get_parameter(name).value for name in names}
        return {**current, **{k: v for k, v in changes.items() if k in current}}

    def _build(self, changes: dict[str, Any]) -> Settings:
        values = self._values(changes)
        stereo = None
        if self._stereo_names:
            stereo = StereoParams(**{n: values[n] for n in self._stereo_names}).validate()
        options = NodeOptions(**{n: values[n] for n in self._option_names}).validate()
        return Settings(stereo, options)

    def _expand_aliases(self, parameters: list[Parameter]) -> list[Parameter]:
        """`ros2 param set stereo_algorithm 1` also sets matcher, in the same atomic change."""
        out = list(parameters)
        for parameter in parameters:
            if parameter.name in COMPAT_ALIASES and parameter.value is not None:
                try:
                    mapped = translate_aliases({parameter.name: parameter.value})
                except ParameterError:
                    continue  # _validate refuses it with the reason
                out.extend(Parameter(name, value=value) for name, value in mapped.items())
        return out

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters}
        try:
            for alias in COMPAT_ALIASES:
                if changes.get(alias) is not None:
                    translate_aliases({alias: changes[alias]})
            self._build(changes)
        except (ParameterError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply(self, parameters: list[Parameter]) -> None:
        del parameters  # the new values are already stored on the node
        self.settings = self._build({})
        self._on_change(self.settings)


def render_config_yaml() -> str:
    """config/stereo_depth.yaml, generated from the dataclasses so it never drifts from them.

    Regenerate after adding a parameter: `python -m stereo_depth.ros.parameters > config/stereo_depth.yaml`.
    """
    lines = [
        "# Every parameter of the stereo_depth nodes with its default (the `default` profile).\n"
        "# Generated by `python -m stereo_depth.ros.parameters > config/stereo_depth.yaml`; do not edit by hand.\n"
        "# Load with:  --ros-args --params-file config/stereo_depth.yaml   (or params_file:= in the launch file)\n"
        "# Values given here (or with -p) override the profile's: delete a processing line to let `profile`\n"
        "# decide it. Each node reads the parameters it declares and ignores the others.\n"
        "/**:\n  ros__parameters:\n"
        f"    # Named set of defaults, read at start-up only: {', '.join(PROFILES)}\n"
        "    profile: default\n"
    ]
    sections = (
        (
            "processing (stereo_node, disparity_node); stereo_image_proc's names where the meaning is the same",
            StereoParams,
        ),
        ("node: inputs, sync, QoS, outputs (each node declares the ones it uses)", NodeOptions),
    )
    for title, cls in sections:
        lines.append(f"    # --- {title}\n")
        for f in dataclasses.fields(cls):
            spec = f.metadata
            bounds = f" [{spec['min']} .. {spec['max']}]" if spec.get("min") is not None else ""
            lines.append(f"    # {spec['description']}{bounds}\n    {f.name}: {_yaml_value(getattr(cls(), f.name))}\n")
        if cls is StereoParams:
            lines.append(
                "    # stereo_image_proc aliases, unset unless given: stereo_algorithm (0 bm, 1 sgbm) sets matcher;\n"
                "    # full_dp: true sets sgbm_mode 1\n"
            )
    return "".join(lines)


def _yaml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if value == "":
        return "''"  # an empty string, not YAML's null
    return str(value)


if __name__ == "__main__":
    print(render_config_yaml(), end="")
