"""How an option is declared: a dataclass field whose metadata holds its doc, range and choices.

The option classes (`StereoParams` here in core, the output and node options in `stereo_depth.options`)
are made of such fields, so that the ROS parameter descriptors, the config YAML, docs/parameters.md
and the command-line flags are all read from one statement per option. Pure Python, no ROS.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from stereo_depth.errors import ParameterError

T = TypeVar("T")


@dataclass(frozen=True)
class OptionSpec:
    """What is said about an option besides its name, type and default."""

    doc: str
    lo: float | None = None  # inclusive range, both or neither
    hi: float | None = None
    step: float = 0  # ROS descriptors' step (0: any value in range)
    choices: tuple[Any, ...] = ()  # the only values allowed, when not empty


def option(
    default: Any,
    doc: str,
    lo: float | None = None,
    hi: float | None = None,
    step: float = 0,
    *,
    choices: Sequence[Any] = (),
) -> Any:
    """A dataclass field declaring one option (name and type: the field's; the rest here)."""
    return field(default=default, metadata={"spec": OptionSpec(doc, lo, hi, step, tuple(choices))})


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
        elif spec.lo is not None and not spec.lo <= value <= spec.hi:
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


def coerced(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    """`values` (those that are fields of `cls`) converted to the fields' types."""
    kinds = {f.name: f.type for f in dataclasses.fields(cls)}
    return {name: coerce(name, value, kinds[name]) for name, value in values.items() if name in kinds}
