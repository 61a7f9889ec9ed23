"""How an option is declared: a dataclass field whose metadata holds its doc, range and choices.

The option classes (`StereoParams` here in core, the output and node options in `stereo_depth.options`)
are made of such fields, so that the ROS parameter descriptors, the config YAML, docs/parameters.md
and the command-line flags are all read from one statement per option. Pure Python, no ROS.

An option may hold a list of numbers: `option((0.0, 0.0, 1.0), doc, lo, hi, length=3)` (a tuple of floats,
each in [lo, hi]) or a pose, `pose_option(doc)` (a `Pose`, given as `[x, y, z, qx, qy, qz, qw]`, unset by
default). ROS declares both as double arrays; integers are taken where doubles are declared.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from numbers import Real
from typing import Any, TypeVar

from stereo_depth.core.pose import POSE_LENGTH, UNSET_POSE, Pose
from stereo_depth.errors import ParameterError

T = TypeVar("T")


@dataclass(frozen=True)
class OptionSpec:
    """What is said about an option besides its name, type and default."""

    doc: str
    lo: float | None = None  # inclusive range, both or neither (of each number, for a list)
    hi: float | None = None
    step: float = 0  # ROS descriptors' step (0: any value in range)
    choices: tuple[Any, ...] = ()  # the only values allowed, when not empty
    length: int = 0  # a list of this many numbers (a tuple of floats, or a Pose); 0: one value


def option(
    default: Any,
    doc: str,
    lo: float | None = None,
    hi: float | None = None,
    step: float = 0,
    *,
    choices: Sequence[Any] = (),
    length: int = 0,
) -> Any:
    """A dataclass field declaring one option (name and type: the field's; the rest here). With `length`,
    a list of that many numbers: the default a tuple of floats, `lo` and `hi` the range of each."""
    return field(default=default, metadata={"spec": OptionSpec(doc, lo, hi, step, tuple(choices), length)})


def pose_option(doc: str) -> Any:
    """A `Pose` option, `[x, y, z, qx, qy, qz, qw]` (metres, unit quaternion); unset (seven zeros) by
    default, which `Pose.is_set` tells."""
    return option(UNSET_POSE, doc, length=POSE_LENGTH)


def spec_of(f: dataclasses.Field[Any]) -> OptionSpec:
    spec: OptionSpec = f.metadata["spec"]
    return spec


def option_names(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def range_problems(options: object) -> list[str]:
    """Each value outside its field's range or choices, as the reason to refuse it."""
    problems = []
    for f in dataclasses.fields(options):  # type: ignore[arg-type]
        spec, value = spec_of(f), getattr(options, f.name)
        if spec.choices and value not in spec.choices:
            problems.append(f"{f.name} '{value}' is unknown; choose one of {', '.join(map(str, spec.choices))}")
        elif spec.lo is not None:
            outside = [v for v in (value if spec.length else (value,)) if not spec.lo <= v <= spec.hi]
            if outside and spec.length:
                problems.append(f"{f.name} {plain_value(value)}: {outside[0]} is outside [{spec.lo}, {spec.hi}]")
            elif outside:
                problems.append(f"{f.name} {value} is outside [{spec.lo}, {spec.hi}]")
    return problems


def check_ranges(options: T) -> T:
    """`options`, or ParameterError with the first value outside its range or choices."""
    problems = range_problems(options)
    if problems:
        raise ParameterError(problems[0])
    return options


def coerce(name: str, value: Any, kind: Any) -> Any:
    """A value given as text or a looser type (CLI, YAML) as the field type `kind` ('int' or int ...)."""
    try:
        if kind in ("bool", bool):
            if isinstance(value, str):
                if value.lower() in ("true", "1", "yes", "on"):
                    return True
                if value.lower() in ("false", "0", "no", "off"):
                    return False
                raise ValueError(value)
            return bool(value)
        if kind in ("int", int):
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            return int(value)
        if kind in ("float", float):
            return float(value)
        return str(value)
    except (TypeError, ValueError) as exc:
        msg = f"{name}: {value!r} is not a valid {kind}"
        raise ParameterError(msg) from exc


def is_pose(f: dataclasses.Field[Any]) -> bool:
    return f.type in ("Pose", Pose)


def coerce_field(f: dataclasses.Field[Any], value: Any) -> Any:
    """`value` as option field `f` holds it: a list option's numbers as a tuple of floats or a Pose."""
    length = spec_of(f).length
    if not length:
        return coerce(f.name, value, f.type)
    numbers = _numbers(f.name, value, length, "a pose [x, y, z, qx, qy, qz, qw]" if is_pose(f) else "")
    if not is_pose(f):
        return numbers
    try:
        return Pose.from_list(numbers)
    except ParameterError as exc:
        msg = f"{f.name}: {exc}"
        raise ParameterError(msg) from exc


def _numbers(name: str, value: Any, length: int, wanted: str) -> tuple[float, ...]:
    """A list of `length` finite numbers as floats; integers too (ROS's YAML reads `[0, 0, 1]` as integers),
    and number text (PyYAML reads `1e-3` as text where ROS reads a double). `wanted`: what to ask for."""
    wanted = wanted or f"a list of {length} numbers"
    if isinstance(value, str | bytes) or not isinstance(value, Iterable):
        msg = f"{name}: {value!r} is not {wanted}, e.g. [{', '.join(['0.0'] * length)}]"
        raise ParameterError(msg)
    items = list(value)
    if len(items) != length:
        msg = f"{name}: {items} has {len(items)} values; give {wanted}"
        raise ParameterError(msg)
    try:
        numbers = tuple(float(v) for v in items if isinstance(v, Real | str) and not isinstance(v, bool))
    except ValueError:
        numbers = ()
    if len(numbers) != length or not all(math.isfinite(v) for v in numbers):
        msg = f"{name}: {items} is not {wanted}"
        raise ParameterError(msg)
    return numbers


def plain_value(value: Any) -> Any:
    """An option's value as ROS parameters and YAML hold it: a list of floats for a list or pose option."""
    if isinstance(value, Pose):
        return value.as_list()
    if isinstance(value, tuple):
        return [float(v) for v in value]
    return value


def coerced(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    """`values` (those that are fields of `cls`) converted to the fields' types."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    return {name: coerce_field(fields[name], value) for name, value in values.items() if name in fields}
