"""Options the commands share: --profile, --set name=value; which topics and calibration a bag gives."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereo_depth.formats.calibration_files import read_stereo_calibration

if TYPE_CHECKING:
    from stereo_depth.bag.reader import TopicChoice

from stereo_depth.core.option_fields import plain_value, spec_of
from stereo_depth.core.params import PROFILES, StereoParams, make_params, parse_assignments
from stereo_depth.options import list_option_names, list_value


def add_param_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", default="default", choices=sorted(PROFILES), help="named parameter set")
    parser.add_argument(
        "--set",
        dest="assignments",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override one parameter (repeatable), e.g. --set disparity_range=128; a list as YAML: "
        "--set 'NAME=[0.1, 0, 0]'",
    )


def assignments(items: list[str]) -> dict[str, Any]:
    """`--set name=value` items; a list option's value (`[0, 0, 1]`) read as YAML, as ROS's `-p` reads it."""
    lists = list_option_names()
    return {
        name: list_value(name, value) if name in lists else value for name, value in parse_assignments(items).items()
    }


def params_from_args(args: argparse.Namespace, extra: Mapping[str, object] | None = None) -> StereoParams:
    overrides: dict[str, object] = dict(extra or {})
    overrides.update(assignments(args.assignments))
    return make_params(args.profile, overrides)


def add_topic_options(parser: argparse.ArgumentParser, with_calibration: bool = True) -> None:
    """For every command that reads a bag: its stereo topics and, where it has none, its calibration."""
    parser.add_argument("--namespace", help="which stereo set to read when the bag holds several")
    parser.add_argument("--left", metavar="TOPIC", help="left image topic (Image or CompressedImage), with --right")
    parser.add_argument("--right", metavar="TOPIC", help="right image topic, with --left")
    parser.add_argument("--left-info", metavar="TOPIC", help="left camera_info (default: beside --left)")
    parser.add_argument("--right-info", metavar="TOPIC", help="right camera_info (default: beside --right)")
    if not with_calibration:
        return
    parser.add_argument(
        "--camera-info",
        type=Path,
        metavar="FILE_OR_DIR",
        help="calibration instead of the bag's camera_info: a Kalibr camchain.yaml, a folder with left.yaml + "
        "right.yaml, or a EuRoC folder (cam0/sensor.yaml + cam1/sensor.yaml)",
    )


def topic_choice(args: argparse.Namespace, need_info: bool = True) -> TopicChoice:
    """What add_topic_options' flags chose; `need_info` False: the images are all the command reads."""
    from stereo_depth.bag.reader import TopicChoice  # rosbags only when a bag is read

    path = getattr(args, "camera_info", None)
    calibration = read_stereo_calibration(path) if path is not None else None
    return TopicChoice(args.namespace, args.left, args.right, args.left_info, args.right_info, calibration, need_info)


def add_option_flags(parser: argparse.ArgumentParser, options: type, names: Sequence[str]) -> None:
    """One flag per option, derived from its field: `queue_size` -> `--queue-size N`, a bool ->
    `--approximate-sync` / `--no-approximate-sync`, a list -> `--name '[X, ...]'` (YAML); its doc is the
    help. Not given: None (the parameter file's value or the default applies)."""
    fields = {f.name: f for f in dataclasses.fields(options)}
    for name in names:
        f, default = fields[name], plain_value(getattr(options(), name))
        flag, doc = "--" + name.replace("_", "-"), spec_of(f).doc.replace("%", "%%")
        if f.type in ("bool", bool):
            parser.add_argument(flag, dest=name, action=argparse.BooleanOptionalAction, default=None, help=doc)
        elif spec_of(f).length:
            parser.add_argument(
                flag, dest=name, type=partial(list_value, name), metavar="[X, ...]", help=f"{doc} (default {default})"
            )
        else:
            kind, metavar = {"int": (int, "N"), "float": (float, "X")}.get(str(f.type), (str, "TEXT"))
            parser.add_argument(flag, dest=name, type=kind, metavar=metavar, help=f"{doc} (default {default})")
