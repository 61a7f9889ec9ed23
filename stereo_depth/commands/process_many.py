"""`stereo-depth process IN... --out-dir DIR`: many bags (and long bags in shards) at once.

The options and the printing of a fleet run; the work is in `stereo_depth.fleet`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stereo_depth.bag.process import ProcessOptions
from stereo_depth.core.params import StereoParams
from stereo_depth.errors import ParameterError
from stereo_depth.fleet.run import FleetSettings, process_many


def add_fleet_options(parser: argparse.ArgumentParser) -> None:
    fleet = parser.add_argument_group("many bags (with --out-dir)")
    fleet.add_argument(
        "--out-dir",
        type=Path,
        metavar="DIR",
        help="process every input into DIR/<input name>; finished ones are skipped",
    )
    fleet.add_argument(
        "--jobs",
        type=int,
        metavar="N",
        help="local worker processes (default: this machine's cores; 1: in this process)",
    )
    fleet.add_argument(
        "--ray",
        nargs="?",
        const="",
        metavar="ADDRESS",
        help="run every bag or shard as a Ray task: alone, on a new local Ray instance; 'auto' or ray://HOST:PORT "
        "joins a cluster (inputs and DIR must be at the same paths on every node)",
    )
    fleet.add_argument(
        "--shard-seconds",
        type=float,
        metavar="S",
        help="cut bags longer than S seconds into S-second windows processed at once, joined into one output bag",
    )
    fleet.add_argument("--report", type=Path, metavar="FILE", help="write a JSON report per bag to FILE")


def settings_from(args: argparse.Namespace) -> FleetSettings:
    if args.png or args.ply:
        msg = "--png and --ply write one file per frame and are for one bag; leave them out with --out-dir"
        raise ParameterError(msg)
    if args.jobs is not None and args.jobs < 1:
        msg = f"--jobs {args.jobs} must be at least 1"
        raise ParameterError(msg)
    if args.jobs is not None and args.ray is not None:
        msg = "--jobs is for local worker processes; with --ray, Ray places the tasks"
        raise ParameterError(msg)
    if args.shard_seconds is not None and not args.shard_seconds > 0:
        msg = f"--shard-seconds {args.shard_seconds} must be positive"
        raise ParameterError(msg)
    defaults = FleetSettings()
    return FleetSettings(
        jobs=args.jobs or defaults.jobs, ray_address=args.ray, shard_seconds=args.shard_seconds, report=args.report
    )


def check_single_bag_options(args: argparse.Namespace) -> None:
    given = [
        flag
        for flag, value in (
            ("--jobs", args.jobs),
            ("--ray", args.ray),
            ("--shard-seconds", args.shard_seconds),
            ("--report", args.report),
        )
        if value is not None
    ]
    if given:
        verb = "needs" if len(given) == 1 else "need"
        msg = f"{', '.join(given)} {verb} --out-dir DIR (e.g. stereo-depth process IN... --out-dir DIR)"
        raise ParameterError(msg)


def run_many(args: argparse.Namespace, params: StereoParams, options: ProcessOptions) -> int:
    settings = settings_from(args)
    bags = process_many(args.paths, args.out_dir, params, options, settings)
    counts = {status: sum(b.status == status for b in bags) for status in ("done", "skipped", "failed")}
    frames = sum(b.frames_out for b in bags)
    print(
        f"{len(bags)} bags: {counts['done']} processed, {counts['skipped']} skipped (already done), "
        f"{counts['failed']} failed; {frames} frames into {args.out_dir}"
    )
    for bag in bags:
        if bag.status == "failed":
            error = bag.error or "failed"
            print(f"ERROR: {error if bag.input in error else f'{bag.input}: {error}'}", file=sys.stderr)
    return 1 if counts["failed"] else 0
