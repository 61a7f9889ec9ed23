"""The nodes' ROS parameters: declared from the option tables, validated as a whole, applied atomically.

Each parameter is a field of `StereoParams`, `OutputOptions` or `NodeOptions` (stereo_depth.options), whose
doc, range and choices become its descriptor, so `ros2 param describe` and the checks agree.

Start-up order makes `-p profile:=X` work as documented: `profile` is read first, every processing
parameter is then declared with X's value as its default, and rclpy applies explicit `-p` /
`--params-file` values on top. stereo_image_proc's `stereo_algorithm` and `full_dp` are aliases: given
at start-up they set the default of `matcher` / `sgbm_mode`; set at run time they set those parameters.
A list option is a double array; integers given for it (`-p name:=[0, 0, 1]`, `ros2 param set` alike, as
ROS's YAML reads them) are taken as doubles, and so is the text `ros2 param set` sends for a list that
mixes integers and doubles.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from stereo_depth.core.option_fields import coerced, is_pose, plain_value, spec_of
from stereo_depth.core.params import COMPAT_ALIASES, PROFILES, StereoParams, translate_aliases
from stereo_depth.errors import ParameterError
from stereo_depth.options import (
    STARTUP_OPTIONS,
    NodeOptions,
    OutputOptions,
    Settings,
    list_value,
    unknown_parameters_line,
)

OptionClass = type[StereoParams] | type[NodeOptions] | type[OutputOptions]


def _option_fields() -> dict[str, tuple[OptionClass, dataclasses.Field[Any]]]:
    """Each option's name: its class and field."""
    classes: tuple[OptionClass, ...] = (StereoParams, NodeOptions, OutputOptions)
    return {f.name: (cls, f) for cls in classes for f in dataclasses.fields(cls)}


def _describe(f: dataclasses.Field[Any], *, read_only: bool = False) -> ParameterDescriptor:
    spec = spec_of(f)
    descriptor = ParameterDescriptor(description=spec.doc, read_only=read_only)
    if spec.choices:
        descriptor.additional_constraints = f"one of: {', '.join(map(str, spec.choices))}"
    if spec.length:
        descriptor.additional_constraints = f"{spec.length} numbers" + (
            ": x, y, z (metres), qx, qy, qz, qw (a unit quaternion); all zero: unset" if is_pose(f) else ""
        )
    if spec.lo is None or spec.hi is None:
        return descriptor
    lo, hi, step = spec.lo, spec.hi, spec.step
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
        self._fields = _option_fields()
        if with_stereo:
            self._declare_stereo()
        for name in self._option_names:
            cls, f = self._fields[name]
            self._declare(f, getattr(cls(), name), _describe(f, read_only=name in STARTUP_OPTIONS))
        self.settings = self._build({})  # a bad start-up value raises ParameterError here
        self._warn_unknown()
        node.add_pre_set_parameters_callback(self._before_set)
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
            self._declare(f, getattr(base, f.name), _describe(f))
        self._stereo_names = tuple(f.name for f in dataclasses.fields(StereoParams))

    def _declare(self, f: dataclasses.Field[Any], default: Any, descriptor: ParameterDescriptor) -> None:
        overrides: dict[str, Parameter] = getattr(self._node, "_parameter_overrides", {})  # -p, --params-file
        if f.name in overrides:
            overrides[f.name] = self._as_declared(overrides[f.name])
        self._node.declare_parameter(f.name, plain_value(default), descriptor)

    def _values(self, changes: dict[str, Any]) -> dict[str, Any]:
        names = (*self._stereo_names, *self._option_names)
        current = {name: self._node.get_parameter(name).value for name in names}
        return {**current, **{k: v for k, v in changes.items() if k in current}}

    def _build(self, changes: dict[str, Any]) -> Settings:
        values = self._values(changes)
        stereo = None
        if self._stereo_names:
            stereo = StereoParams(**self._given(values, StereoParams)).validate()
        options = NodeOptions(**self._given(values, NodeOptions)).validate()
        output = OutputOptions(**self._given(values, OutputOptions)).validate()
        return Settings(stereo, options, output)

    def _given(self, values: dict[str, Any], cls: OptionClass) -> dict[str, Any]:
        """The values of this node's options that are fields of `cls` (the others keep their defaults), as
        the fields hold them (a list option's tuple or Pose)."""
        names = (*self._stereo_names, *self._option_names)
        return coerced(cls, {n: values[n] for n in names if self._fields[n][0] is cls})

    def _warn_unknown(self) -> None:
        """One start-up warning for -p / --params-file names no stereo_depth node knows (a typo is
        otherwise ignored without a word); rclpy keeps the given values in `_parameter_overrides`."""
        line = unknown_parameters_line(getattr(self._node, "_parameter_overrides", {}))
        if line is not None:
            self._node.get_logger().warning(line)

    def _as_declared(self, parameter: Parameter) -> Parameter:
        """A list option's numbers as the doubles it is declared with (rclpy refuses another type): integers
        (ROS's YAML reads `[0, 0, 1]` so) and the text `ros2 param set` sends for `[0.5, 0, 1]`, a list
        mixing integers and doubles. Anything else is left for rclpy to refuse."""
        field = self._fields.get(parameter.name)
        if field is None or not spec_of(field[1]).length:
            return parameter
        value = parameter.value  # an array.array from the parameter service
        if parameter.type_ == Parameter.Type.STRING:
            try:
                value = list_value(parameter.name, value)
            except ParameterError:
                return parameter
            if not isinstance(value, list):
                return parameter
        elif parameter.type_ != Parameter.Type.INTEGER_ARRAY:
            return parameter
        if not all(type(v) in (int, float) for v in value):
            return parameter
        return Parameter(parameter.name, value=[float(v) for v in value])

    def _before_set(self, parameters: list[Parameter]) -> list[Parameter]:
        """Integer lists as doubles; `ros2 param set stereo_algorithm 1` also sets matcher, in the same
        atomic change."""
        out = [self._as_declared(parameter) for parameter in parameters]
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
