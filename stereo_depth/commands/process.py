"""`stereo-depth process`: a recorded stereo bag into disparity, depth, points2 and left/image_rect."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from typing import Any

import yaml

from stereo_depth.bag.process import ProcessOptions, process_bag
from stereo_depth.bag.reader import SyncPolicy
from stereo_depth.bag.writer import STORAGES
from stereo_depth.commands.common import add_param_options, add_topic_options, topic_choice
from stereo_depth.commands.process_many import add_fleet_options, check_single_bag_options, run_many
from stereo_depth.core.params import COMPAT_ALIASES, StereoParams, field_names, make_params, parse_assignments
from stereo_depth.errors import ParameterError
from stereo_depth.frames import OUTPUTS, OutputOptions, camera_fixes, make_output_options, output_option_names
from stereo_depth.settings import unknown_parameters_line


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
    parser.add_argument(
        "--approximate-sync",
        action="store_true",
        default=None,
        help="pair by nearest stamps instead of equal ones (the node's approximate_sync)",
    )
    parser.add_argument(
        "--approximate-sync-tolerance",
        type=float,
        metavar="SECONDS",
        help="largest stamp difference inside one approximate set (default 0: no limit, as the node)",
    )
    parser.add_argument("--queue-size", type=int, help="messages kept per input while pairing (default 5, as the node)")
    parser.add_argument("--png", type=Path, metavar="DIR", help="write rectified left | colourised disparity per frame")
    parser.add_argument("--ply", type=Path, metavar="DIR", help="write a coloured point cloud (binary PLY) per frame")
    parser.add_argument(
        "--storage", choices=sorted(STORAGES), default="mcap", help="output storage (default %(default)s)"
    )
    parser.add_argument(
        "--outputs",
        nargs="+",
        choices=OUTPUTS,
        default=list(OUTPUTS),
        metavar="NAME",
        help=(
            f"topics to write (default all: {' '.join(OUTPUTS)}; colour and confidence when the input and "
            "matcher give them); a VGA points2 is 10 MB a frame"
        ),
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


def file_parameters(args: argparse.Namespace) -> dict[str, Any]:
    return read_params_file(args.params) if getattr(args, "params", None) else {}


def _given(args: argparse.Namespace) -> tuple[dict[str, Any], dict[str, Any]]:
    """(processing, output) values: those of --params FILE, then --set on top. An unknown --set name
    is an error; unknown keys in the file (it may configure other nodes too) get one warning line."""
    stereo_names, output_names = {*field_names(), *COMPAT_ALIASES}, set(output_option_names())
    from_file = file_parameters(args)
    assignments = parse_assignments(args.assignments)
    for name in assignments:
        if name not in stereo_names | output_names:
            reason = unknown_parameters_line([name]) or f"'{name}' is a live node's option, not used offline"
            msg = f"--set: {reason}"
            raise ParameterError(msg)
    values = {**from_file, **assignments}
    stereo = {k: v for k, v in values.items() if k in stereo_names}
    return stereo, {k: v for k, v in values.items() if k in output_names}


def params_from(args: argparse.Namespace) -> StereoParams:
    """--profile, then the StereoParams keys of --params FILE, then --set (the last one wins)."""
    return make_params(args.profile, _given(args)[0])


def output_options_from(args: argparse.Namespace) -> OutputOptions:
    """The OutputOptions keys of --params FILE, then --set: outputs built as the nodes build them."""
    return make_output_options(_given(args)[1])


def sync_from(args: argparse.Namespace) -> SyncPolicy:
    """Command-line flags, else the node parameters in --params FILE, else the node's defaults."""
    node = file_parameters(args)
    defaults = SyncPolicy()

    def pick(flag: Any, name: str, default: Any) -> Any:
        return flag if flag is not None else node.get(name, default)

    tolerance = float(pick(args.approximate_sync_tolerance, "approximate_sync_tolerance_seconds", 0.0))
    queue_size = int(pick(args.queue_size, "queue_size", defaults.queue_size))
    if tolerance < 0 or queue_size < 1:
        msg = f"approximate sync tolerance {tolerance} must be >= 0 and queue size {queue_size} >= 1"
        raise ParameterError(msg)
    approximate = bool(pick(args.approximate_sync, "approximate_sync", defaults.approximate))
    return SyncPolicy.from_node_parameters(approximate, queue_size, tolerance)


def options_from(args: argparse.Namespace) -> ProcessOptions:
    return ProcessOptions(
        namespace=args.namespace,
        topics=topic_choice(args),
        sync=sync_from(args),
        storage=args.storage,
        compress=args.compress,
        outputs=tuple(args.outputs),
        output=output_options_from(args),
        overwrite=args.overwrite,
        png_dir=args.png,
        ply_dir=args.ply,
    )


def interrupt_on_sigterm() -> None:
    """A `kill` unwinds like Ctrl-C, so the half-written bag is deleted rather than left behind."""

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)


def warn_unknown_file_keys(args: argparse.Namespace) -> None:
    """One line for --params keys no stereo_depth node knows (a typo would otherwise do nothing)."""
    line = unknown_parameters_line(file_parameters(args))
    if line is not None:
        print(f"WARNING: --params {args.params}: {line}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    params = params_from(args)
    warn_unknown_file_keys(args)
    options = options_from(args)
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
