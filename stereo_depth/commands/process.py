"""`stereo-depth process`: a recorded stereo bag into disparity, depth, points2 and left/image_rect."""

from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
from pathlib import Path
from typing import Any

import yaml

from stereo_depth.bag.process import ProcessOptions, process_bag
from stereo_depth.bag.reader import TopicChoice
from stereo_depth.bag.writer import STORAGES
from stereo_depth.commands.common import (
    add_option_flags,
    add_param_options,
    add_topic_options,
    assignments,
    topic_choice,
)
from stereo_depth.commands.process_many import add_fleet_options, check_single_bag_options, run_many
from stereo_depth.core.option_fields import option_names
from stereo_depth.core.params import COMPAT_ALIASES, StereoParams, field_names, make_params
from stereo_depth.errors import ParameterError
from stereo_depth.formats.kalibr import is_camchain, read_camchain_colour
from stereo_depth.frames import DEFAULT_OUTPUTS, OUTPUTS, camera_fixes
from stereo_depth.frames.registered import REGISTERED_OUTPUTS
from stereo_depth.options import (
    SYNC_OPTIONS,
    NodeOptions,
    OutputOptions,
    Settings,
    node_options,
    output_options,
    unknown_parameters_line,
)


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "process",
        help="run the stereo pipeline over a recorded bag and write the results into a new bag",
        description=(
            "Reads a rosbag2 (MCAP, sqlite3) or a ROS 1 .bag, finds its stereo images (left/right, cam0/cam1, "
            "infra1/infra2; image_raw, image_rect or their /compressed) and their camera_info (or --camera-info), "
            "pairs them like stereo_node and writes <ns>/disparity, depth, points2 and left/image_rect with the "
            "input stamps into a new rosbag2."
        ),
    )
    parser.add_argument(
        "paths",
        type=Path,
        nargs="+",
        metavar="PATH",
        help="IN_BAG OUT_BAG; or, with --out-dir DIR, any number of bags and folders searched for bags",
    )
    add_process_options(parser)
    add_fleet_options(parser)
    parser.set_defaults(run=run)


def add_process_options(parser: argparse.ArgumentParser) -> None:
    """Options shared with `demo`: parameters, topic choice, sync policy, output files."""
    add_param_options(parser)
    parser.add_argument(
        "--params", type=Path, metavar="FILE", help="ROS parameter YAML (node: ros__parameters: ...); --set wins"
    )
    add_topic_options(parser)
    add_option_flags(parser, NodeOptions, SYNC_OPTIONS)  # pairing as the node's parameters (and --params) say
    parser.add_argument("--png", type=Path, metavar="DIR", help="write rectified left | colourised disparity per frame")
    parser.add_argument("--ply", type=Path, metavar="DIR", help="write a coloured point cloud (binary PLY) per frame")
    parser.add_argument(
        "--storage", choices=sorted(STORAGES), default="mcap", help="output storage (default %(default)s)"
    )
    parser.add_argument(
        "--outputs",
        nargs="+",
        choices=(*OUTPUTS, *REGISTERED_OUTPUTS),
        default=list(DEFAULT_OUTPUTS),
        metavar="NAME",
        help=(
            f"topics to write (default: {' '.join(DEFAULT_OUTPUTS)}; colour and confidence when the input and "
            "matcher give them; also depth/compressedDepth, points2_clearing, and with rgb_in_left set "
            f"{', '.join(REGISTERED_OUTPUTS)}); a VGA points2 is 10 MB a frame"
        ),
    )
    parser.add_argument(
        "--rgb", metavar="TOPIC", help="colour image topic for the registered outputs (default: <namespace>/rgb/...)"
    )
    parser.add_argument("--rgb-info", metavar="TOPIC", help="colour camera_info (default: beside --rgb)")
    parser.add_argument(
        "--odom",
        metavar="TOPIC",
        help="nav_msgs/Odometry topic the temporal filter moves its history by, with left_in_base set "
        "(default: <namespace>/odom)",
    )
    parser.add_argument(
        "--compress", action="store_true", help="zstd-compress the MCAP chunks (smaller, about 2x slower to write)"
    )
    parser.add_argument("--overwrite", action="store_true", help="replace OUT_BAG if it exists")


def read_params_file(path: Path) -> dict[str, Any]:
    """Every parameter of a ROS parameter file's `ros__parameters` sections, merged in file order.

    `/**` and node-name sections alike, so the file that configures stereo_node configures this too.
    """
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        msg = f"--params {path}: cannot read it as YAML ({exc})"
        raise ParameterError(msg) from exc
    sections = _ros_parameters(document)
    if not sections:
        msg = f"--params {path}: no 'ros__parameters' section; expected node_name: {{ros__parameters: {{...}}}}"
        raise ParameterError(msg)
    merged: dict[str, Any] = {}
    for section in sections:
        merged.update(section)
    return merged


def _ros_parameters(node: Any) -> list[dict[str, Any]]:
    if not isinstance(node, dict):
        return []
    if isinstance(node.get("ros__parameters"), dict):
        return [node["ros__parameters"]]
    return [section for value in node.values() for section in _ros_parameters(value)]


def settings_from(args: argparse.Namespace) -> tuple[StereoParams, Settings]:
    """What `process` (and `demo`) run with, the processing parameters and the rest: --profile, then
    --params FILE (read here, once), then --set and the sync flags on top. An unknown --set name is an
    error; keys of the file that no stereo_depth node knows (it may configure other nodes too) get one
    warning line."""
    from_file = read_params_file(args.params) if getattr(args, "params", None) else {}
    given = assignments(args.assignments)
    stereo_names = {*field_names(), *COMPAT_ALIASES}
    for name in given:
        if name not in stereo_names | set(option_names(OutputOptions)):
            reason = unknown_parameters_line([name]) or f"'{name}' is a live node's option, not used offline"
            msg = f"--set: {reason}"
            raise ParameterError(msg)
    values = {**from_file, **given}
    stereo = make_params(args.profile, {k: v for k, v in values.items() if k in stereo_names})
    line = unknown_parameters_line(from_file)
    if line is not None:
        print(f"WARNING: --params {args.params}: {line}", file=sys.stderr)
    flags = {name: getattr(args, name, None) for name in SYNC_OPTIONS}
    sync = node_options({**from_file, **{k: v for k, v in flags.items() if v is not None}})
    return stereo, Settings(stereo, sync, output_options(values))


def options_from(args: argparse.Namespace, settings: Settings) -> ProcessOptions:
    topics, output = colour_choice(args, topic_choice(args), settings.output)
    topics = dataclasses.replace(topics, odom=getattr(args, "odom", None))
    return ProcessOptions(
        namespace=args.namespace,
        topics=topics,
        sync=settings.options,
        storage=args.storage,
        compress=args.compress,
        outputs=tuple(args.outputs),
        output=output,
        overwrite=args.overwrite,
        png_dir=args.png,
        ply_dir=args.ply,
    )


def colour_choice(
    args: argparse.Namespace, topics: TopicChoice, output: OutputOptions
) -> tuple[TopicChoice, OutputOptions]:
    """The colour camera's topics (--rgb, --rgb-info) and, from a Kalibr camchain with a cam2, its
    calibration and its pose (rgb_in_left, unless --set gives it)."""
    topics = dataclasses.replace(topics, rgb=getattr(args, "rgb", None), rgb_info=getattr(args, "rgb_info", None))
    path = getattr(args, "camera_info", None)
    colour = read_camchain_colour(path) if path is not None and is_camchain(path) else None
    if colour is None:
        return topics, output
    info, pose = colour
    if not output.rgb_in_left.is_set:
        output = dataclasses.replace(output, rgb_in_left=pose)
    return dataclasses.replace(topics, rgb_calibration=info), output


def interrupt_on_sigterm() -> None:
    """A `kill` unwinds like Ctrl-C, so the half-written bag is deleted rather than left behind."""

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)


def run(args: argparse.Namespace) -> int:
    params, settings = settings_from(args)
    options = options_from(args, settings)
    fixes = camera_fixes(options.output)
    if fixes is not None:
        print(f"inputs corrected: {fixes}", file=sys.stderr)
    interrupt_on_sigterm()
    if args.out_dir is not None:
        return run_many(args, params, options)
    check_single_bag_options(args)
    if len(args.paths) != 2:
        msg = f"process takes IN_BAG OUT_BAG, or inputs with --out-dir DIR; got {len(args.paths)} paths"
        raise ParameterError(msg)
    args.in_bag, args.out_bag = args.paths
    summary = process_bag(args.in_bag, args.out_bag, params, options)
    for line in summary.lines():
        print(line)
    print(f"wrote {args.out_bag} ({', '.join(summary.topics)})")
    return 0
