"""`stereo-depth eval`: accuracy and speed of a profile on scene folders with ground truth."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.commands.common import add_param_options, params_from_args
from stereo_depth.core.metrics import accuracy, comparison_picture
from stereo_depth.core.params import parse_assignments
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import SceneError, load_scene

COLUMNS = ("bad1", "bad2", "bad4", "bad2_est", "density", "epe", "ms")


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser("eval", help="accuracy against ground truth on scene folders")
    parser.add_argument("scenes", nargs="+", type=Path, metavar="SCENE_DIR")
    add_param_options(parser)
    parser.add_argument("--json", type=Path, help="write the table as JSON")
    parser.add_argument("--save", type=Path, metavar="DIR", help="write left|GT|ours|error PNG per scene")
    parser.add_argument("--repeat", type=int, default=1, help="time the best of N runs per scene")
    parser.set_defaults(run=run)


def evaluate_scene(
    folder: Path, args: argparse.Namespace, warm_up: bool = False
) -> tuple[dict[str, object], np.ndarray | None]:
    scene = load_scene(folder)
    if scene.gt is None:
        msg = f"{folder}: no ground truth (disp_gt.png / disp_gt.pfm)"
        raise SceneError(msg)
    given = parse_assignments(args.assignments)
    extra = {} if "disparity_range" in given else {"disparity_range": scene.disparity_range()}
    pipeline = StereoPipeline(params_from_args(args, extra))
    if warm_up:  # one-time costs (loading the census core, OpenCV's first allocations) are not per frame
        pipeline.process(scene.left, scene.right, None, rectified=True, want_points=False)
    best = float("inf")
    result = None
    for _ in range(max(1, args.repeat)):
        start = time.perf_counter()
        result = pipeline.process(scene.left, scene.right, None, rectified=True, want_points=False)
        best = min(best, (time.perf_counter() - start) * 1000.0)
    assert result is not None
    acc = accuracy(result.disparity, scene.gt, scene.mask)
    row: dict[str, object] = {"scene": scene.name, **acc.as_dict(), "ms": best}
    picture = None
    if args.save:
        picture = comparison_picture(scene.left, scene.gt, result.disparity, scene.mask, scene.name)
    return row, picture


def _format(row: dict[str, object]) -> str:
    cells = [f"{row[c]:9.3f}" if c != "ms" else f"{row[c]:9.1f}" for c in COLUMNS]  # type: ignore[str-format]
    return f"{row['scene']!s:36s}" + "".join(cells)


def run(args: argparse.Namespace) -> int:
    params_from_args(args)  # refuse bad parameters before any work
    for folder in args.scenes:
        if not folder.is_dir():
            msg = f"{folder}: not a scene folder"
            raise SceneError(msg)
    print(f"{'scene':36s}" + "".join(f"{c:>9s}" for c in COLUMNS))
    rows = []
    for index, folder in enumerate(args.scenes):
        row, picture = evaluate_scene(folder, args, warm_up=index == 0)
        rows.append(row)
        print(_format(row), flush=True)
        if picture is not None:
            args.save.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(args.save / (str(row["scene"]).replace("/", "_") + ".png")), picture)
    mean = {c: float(np.nanmean([float(r[c]) for r in rows])) for c in COLUMNS}  # type: ignore[arg-type]
    print(_format({"scene": f"mean ({len(rows)} scenes, {args.profile})", **mean}))
    if args.json:
        args.json.write_text(json.dumps({"profile": args.profile, "scenes": rows, "mean": mean}, indent=2))
    return 0
