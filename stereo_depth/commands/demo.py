"""`stereo-depth demo` (`make demo`): the bundled bags through the default pipeline, into out/.

EuRoC's raw, distorted frames show the whole chain (rectify, match, depth, points); the Middlebury
frames add an accuracy check against their ground truth. Everything it writes is under OUT_DIR and
is replaced on the next run.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from stereo_depth.bag.ground_truth import read_ground_truth_index
from stereo_depth.bag.process import FrameCallback, ProcessOptions, ProcessSummary, process_bag
from stereo_depth.commands.common import add_param_options
from stereo_depth.commands.process import settings_from
from stereo_depth.core.metrics import accuracy
from stereo_depth.core.params import StereoParams
from stereo_depth.errors import BagError
from stereo_depth.frames import FrameOutputs
from stereo_depth.options import Settings
from stereo_depth.sync import StereoSet

BAGS = Path(__file__).resolve().parents[2] / "bags"


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser("demo", help="process the bundled bags into out/: pictures, a PLY, timings")
    parser.add_argument("--out", type=Path, default=Path("out"), metavar="OUT_DIR", help="default %(default)s")
    parser.add_argument("--bags", type=Path, default=BAGS, metavar="DIR", help="where euroc_raw and middlebury are")
    add_param_options(parser)
    parser.set_defaults(run=run)


def _process(
    name: str,
    args: argparse.Namespace,
    params: StereoParams,
    settings: Settings,
    on_frame: FrameCallback | None = None,
) -> ProcessSummary:
    source = args.bags / name
    if not source.is_dir():
        msg = f"{source} is missing; the demo needs the bundled bags (git checkout of bags/)"
        raise BagError(msg)
    options = ProcessOptions(
        output=settings.output,
        overwrite=True,
        png_dir=args.out / f"{name}_png",
        ply_dir=args.out / f"{name}_ply",
        ply_frames=1,
    )
    summary = process_bag(source, args.out / name, params, options, on_frame)
    print(f"\n== {source} -> {args.out / name}")
    for line in summary.lines():
        print(line)
    print(f"pictures (rectified left | disparity, black = none): {options.png_dir}/ ({len(summary.pictures)} files)")
    print(f"point cloud (PLY, opens in MeshLab / CloudCompare): {summary.clouds[0] if summary.clouds else 'none'}")
    return summary


def _middlebury_accuracy(args: argparse.Namespace, params: StereoParams, settings: Settings) -> None:
    truth = read_ground_truth_index(args.bags / "middlebury_gt")
    rows: list[str] = []

    def check(index: int, frame: StereoSet, out: FrameOutputs) -> None:
        gt = truth.get(frame.stamp_ns)
        if gt is not None:
            acc = accuracy(out.disparity, gt.disparity, gt.mask)
            rows.append(
                f"  {gt.scene:30s} bad-2 {acc.bad2:6.1%}  bad-2 of estimated {acc.bad2_est:6.1%}  "
                f"density {acc.density:6.1%}"
            )

    _process("middlebury", args, params, settings, check)
    print("accuracy against Middlebury ground truth (non-occluded pixels):")
    print("\n".join(rows) if rows else "  no frame matched the ground truth stamps")


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    params, settings = settings_from(args)  # refuse bad parameters before any work
    args.out.mkdir(parents=True, exist_ok=True)
    euroc = _process("euroc_raw", args, params, settings)
    _middlebury_accuracy(args, params, settings)
    if euroc.pictures:
        print(f"\nlook first at {euroc.pictures[len(euroc.pictures) // 2]}")
    print(f"demo done in {time.perf_counter() - start:.1f} s; everything is under {args.out}/")
    return 0
