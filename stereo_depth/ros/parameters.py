"""The nodes' ROS parameters: declared from the option tables, validated as a whole, applied atomically.

Each parameter is a field of `StereoParams`, `OutputOptions` or `NodeOptions` (stereo_depth.options), whose
doc, range and choices become its descriptor, so `ros2 param describe` and the checks agree.

Start-up order makes `-p profile:=X` work as documented: `profile` is read first, every processing
parameter is then declared with X's value as its default, and rclpy applies explicit `-p` /
`--params-file` values on top. stereo_image_proc's `stereo_algorithm` and `full_dp` are aliases: given
at start-up they set the default of `matcher` / `sgbm_mode`; set at run time they set those parameters.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from stereo_depth.core.option_fields import spec_of
from stereo_depth.core.params import COMPAT_ALIASES, PROFILES, StereoParams, translate_aliases
from stereo_depth.errors import ParameterError
from stereo_depth.options import STARTUP_OPTIONS, NodeOptions, OutputOptions, Settings, unknown_parameters_line

_OPTION_CLASS: dict[str, type[NodeOptions] | type[OutputOptions]] = {
    f.name: cls for cls in (NodeOptions, OutputOptions) for f in dataclasses.fields(cls)
}
_FIELDS = {f.name: f for cls in (NodeOptions, OutputOptions) for f in dataclasses.fields(cls)}


def _describe(f: dataclasses.Field[Any], *, read_only: bool = False) -> ParameterDescriptor:
    spec = spec_of(f)
    descriptor = ParameterDescriptor(description=spec.doc, read_only=read_only)
    if spec.choices:
        descriptor.additional_constraints = f"one of: {', '.join(map(str, spec.choices))}"
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
        if with_stereo:
            self._declare_stereo()
        for name in self._option_names:
            cls = _OPTION_CLASS[name]
            descriptor = _describe(_FIELDS[name], read_only=name in STARTUP_OPTIONS)
            node.declare_parameter(name, getattr(cls(), name), descriptor)
        self.settings = self._build({})  # a bad start-up value raises ParameterError here
        self._warn_unknown()
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
            node.declare_parameter(f.name, getattr(base, f.name), _describe(f))
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
        options = NodeOptions(**self._given(values, NodeOptions)).validate()
        output = OutputOptions(**self._given(values, OutputOptions)).validate()
        return Settings(stereo, options, output)

    def _given(self, values: dict[str, Any], cls: type[NodeOptions] | type[OutputOptions]) -> dict[str, Any]:
        """The values of this node's options that are fields of `cls` (the others keep their defaults)."""
        return {n: values[n] for n in self._option_names if _OPTION_CLASS[n] is cls}

    def _warn_unknown(self) -> None:
        """One start-up warning for -p / --params-file names no stereo_depth node knows (a typo is
        otherwise ignored without a word); rclpy keeps the given values in `_parameter_overrides`."""
        line = unknown_parameters_line(getattr(self._node, "_parameter_overrides", {}))
        if line is not None:
            self._node.get_logger().warning(line)

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
