"""Accuracy on scenes with ground truth: the profiles side by side, what the confidence is worth, and what
the left-right check (disp12_max_diff) keeps.

    .venv/bin/python bench/accuracy.py profiles SCENE_DIR... [--picture PATH] [--repeat 3] [--markdown]
    .venv/bin/python bench/accuracy.py confidence SCENE_DIR... [--profile quality] [--threshold 0.5]
    .venv/bin/python bench/accuracy.py left-right SCENE_DIR...

profiles: each profile's mean bad-2, bad-2 of the estimated pixels, density and time per scene (the best
of --repeat), `default` first (the baseline of the ratio); --picture draws the first scene (left | ground
truth | each profile). Bundled scenes: test/data/scenes; larger sets (Middlebury, KITTI) are passed as
folders of scene folders, as `--data DIR` does for `make bench-docs`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.metrics import Accuracy, accuracy, colorize_disparity, label
from stereo_depth.core.params import PROFILES, make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import Scene, load_scene

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row, times

DISP12_SETTINGS = (-1, 0, 1, 3)  # check off, stereo_image_proc's value, 1 and 3 px


def scenes_with_truth(folders: list[Path]) -> list[Scene]:
    found = [scene for scene in map(load_scene, folders) if scene.gt is not None]
    if not found:
        raise SystemExit("ERROR: none of the scenes has ground truth")
    return found


def timed_profile(profile: str, scene: Scene, repeat: int) -> tuple[Accuracy, float, np.ndarray]:
    """(accuracy, best ms of `repeat` after a warm-up, disparity) of one profile on one scene."""
    pipeline = StereoPipeline(make_params(profile, {"disparity_range": scene.disparity_range()}))
    pipeline.process(scene.left, scene.right, None, rectified=True, want_points=False)  # loads the kernels
    runs = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = pipeline.process(scene.left, scene.right, None, rectified=True, want_points=False)
        runs.append((time.perf_counter() - start) * 1000.0)
    assert scene.gt is not None
    return accuracy(result.disparity, scene.gt, scene.mask), min(runs), result.disparity


def profiles(args: argparse.Namespace) -> None:
    scenes = scenes_with_truth(args.scenes)
    top = float(np.nanmax(scenes[0].gt))  # type: ignore[arg-type]
    panels = [label(scenes[0].left, scenes[0].name), label(colorize_disparity(scenes[0].gt, top), "ground truth")]  # type: ignore[arg-type]
    print(f"{len(scenes)} scenes with ground truth, time: the best of {args.repeat} runs per scene, means over scenes:")
    print(
        table_header(("profile", "bad-2", "bad-2 of estimated", "density", "ms per scene", f"vs `{args.profiles[0]}`"))
    )
    baseline_ms = 0.0
    for profile in args.profiles:
        measured = [timed_profile(profile, scene, args.repeat) for scene in scenes]
        bad2, bad2_est, density, ms = (
            float(np.mean(values))
            for values in zip(*((acc.bad2, acc.bad2_est, acc.density, ms) for acc, ms, _ in measured), strict=True)
        )
        baseline_ms = baseline_ms or ms
        cells = (
            f"`{profile}`",
            f"{bad2:.3f}",
            f"{bad2_est:.3f}",
            f"{density:.3f}",
            f"{ms:.1f}",
            times(ms / baseline_ms),
        )
        print(table_row(cells), flush=True)
        first, first_ms, disparity = measured[0]
        panels.append(
            label(colorize_disparity(disparity, top), f"{profile}: bad-2 {first.bad2:.3f}, {first_ms:.0f} ms")
        )
    if args.picture:
        half = (len(panels) + 1) // 2  # two rows, padded with black
        panels += [np.zeros_like(panels[0])] * (2 * half - len(panels))
        args.picture.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(args.picture), np.vstack([np.hstack(panels[:half]), np.hstack(panels[half:])]))
        print(f"\npicture: {args.picture}", file=sys.stderr)


def confidence(args: argparse.Namespace) -> None:
    """bad-2 among the pixels at or above the threshold against bad-2 over all estimated pixels."""
    rows = []
    for scene in scenes_with_truth(args.scenes):
        params = make_params(args.profile, {"disparity_range": scene.disparity_range()})
        result = StereoPipeline(params).process(scene.left, scene.right, None, rectified=True, want_points=False)
        if result.confidence is None:
            raise SystemExit(f"ERROR: profile {args.profile} gives no confidence")
        assert scene.gt is not None
        sure = np.where(result.confidence >= args.threshold, result.disparity, np.nan)
        everything, kept = accuracy(result.disparity, scene.gt, scene.mask), accuracy(sure, scene.gt, scene.mask)
        rows.append((everything.bad2_est, kept.bad2_est, kept.density / everything.density))
    overall, confident, share = (float(np.mean(values)) for values in zip(*rows, strict=True))
    print(f"profile `{args.profile}`, {len(rows)} scenes, means over scenes:")
    columns = ("pixels", "bad-2 of estimated", "share of the estimated pixels", "vs all estimated")
    print(table_header(columns))
    print(table_row(("all estimated", f"{overall:.4f}", "1.00", times(1.0))))
    cells = (f"confidence >= {args.threshold}", f"{confident:.4f}", f"{share:.2f}", times(confident / overall))
    print(table_row(cells))


def left_right(args: argparse.Namespace) -> None:
    print("valid pixels / bad-2 of the estimates, profile `default`, by disp12_max_diff:")
    print(table_header(("scene", "matcher", *(f"{d}: valid / bad-2" for d in DISP12_SETTINGS))))
    for folder in args.scenes:
        scene = load_scene(folder)
        for matcher in ("bm", "sgbm", "census_sgm"):
            cells = []
            for disp12 in DISP12_SETTINGS:
                params = make_params("default", {"matcher": matcher, "disp12_max_diff": disp12})
                disparity = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True).disparity
                valid = float(np.isfinite(disparity).mean()) * 100
                bad2 = accuracy(disparity, scene.gt, scene.mask).bad2_est * 100 if scene.gt is not None else np.nan
                cells.append(f"{valid:.1f} % / {bad2:.1f} %")
            print(table_row((folder.name, matcher, *cells)), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    questions = parser.add_subparsers(dest="question", required=True)
    compared = questions.add_parser("profiles", help="every profile on the scenes: accuracy and time")
    compared.add_argument(
        "--profiles", nargs="+", choices=sorted(PROFILES), default=["default", "fast", "quality", "stereo_image_proc"]
    )
    compared.add_argument("--repeat", type=int, default=3)
    compared.add_argument("--picture", type=Path, help="draw the first scene's disparities here (PNG)")
    confident = questions.add_parser("confidence", help="bad-2 of the confident pixels against all estimated")
    confident.add_argument("--profile", default="quality")
    confident.add_argument("--threshold", type=float, default=0.5)
    questions.add_parser("left-right", help="valid pixels and bad-2 by disp12_max_diff, per matcher")
    for question in questions.choices.values():
        question.add_argument("scenes", nargs="+", type=Path)
        question.add_argument("--markdown", action="store_true", help="(always markdown tables)")
    args = parse_bench_arguments(parser, "(always markdown tables)")
    {"profiles": profiles, "confidence": confidence, "left-right": left_right}[args.question](args)


if __name__ == "__main__":
    main()
