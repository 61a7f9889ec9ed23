"""Accuracy on scenes with ground truth: the profiles side by side, what the confidence is worth, and what
the left-right check (disp12_max_diff) keeps.

    .venv/bin/python bench/accuracy.py profiles SCENE_DIR... [--picture PATH] [--repeat 3] [--markdown]
    .venv/bin/python bench/accuracy.py confidence SCENE_DIR... [--profile quality] [--threshold 0.5]
    .venv/bin/python bench/accuracy.py left-right SCENE_DIR...
    .venv/bin/python bench/accuracy.py sparsification SCENE_DIR...
    .venv/bin/python bench/accuracy.py too-near SCENE_DIR... [--range 64]
    .venv/bin/python bench/accuracy.py removed SCENE_DIR...
    .venv/bin/python bench/accuracy.py check-cost SCENE_DIR [--repeat 15]

sparsification: per matcher (as its profile runs it, nothing filled), confidence threshold against the
share of the valid pixels kept and bad-2 of those, pooled over the scenes; then the threshold that keeps
80 % and its bad-2 against that of all valid pixels. too-near: the scenes whose ground truth exceeds --range,
run at it with near_detection off and on: the share of the pixels beyond the range (ground truth at
least 2 px past its top: nearer, output at the top, is right within 2 px) output valid, the density of
those within it (2 px below its top), and the beyond-range pixels that would cast a clearing ray (at the
smallest disparity searched); strict: the same with no 2 px margin. removed: at each
scene's own range, what near_detection removes from `default` and `quality`, and the bad-2 of the
estimated pixels that follows. check-cost: at 640x480, the time of the confidence and of too-near
detection against the match's, interleaved, per matcher.

profiles: each profile's mean bad-2, bad-2 of the estimated pixels, density and time per scene (the best
of --repeat), `default` first (the baseline of the ratio); --picture draws the first scene (left | ground
truth | each profile). Bundled scenes: test/data/scenes; larger sets (Middlebury, KITTI) are passed as
folders of scene folders, as `--data DIR` does for `make bench-docs`.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.confidence import neighbourhood_confidence
from stereo_depth.core.matching import create_matcher
from stereo_depth.core.memory import keep_freed_memory
from stereo_depth.core.metrics import Accuracy, accuracy, colorize_disparity, evaluation_mask, label
from stereo_depth.core.params import PROFILES, StereoParams, make_params
from stereo_depth.core.pipeline import StereoPipeline, to_grey8
from stereo_depth.core.too_near import TooNearDetector
from stereo_depth.formats.scenes import Scene, load_scene

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row, times

DISP12_SETTINGS = (-1, 0, 1, 3)  # check off, stereo_image_proc's value, 1 and 3 px
# each matcher as its profile runs it, without what changes its valid pixels after matching
MATCHER_PROFILES: dict[str, tuple[str, dict[str, object]]] = {
    "bm": ("fast", {"fill_holes": False, "downsample": 1}),
    "sgbm": ("default", {}),
    "census_sgm": ("quality", {"confidence_threshold": 0.0}),
}
THRESHOLDS = (0.0, 0.05, 0.1, 0.25, 0.4, 0.5, 0.6, 0.75, 0.9)
NEAR_PROFILES = ("default", "fast", "quality")
NEAR_MARGIN = 2.0  # px: ground truth this far past the range's top counts as beyond it, this far below as within
VGA = (640, 480)


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


def pooled_confidence(scenes: list[Scene], profile: str, values: dict[str, object]) -> tuple[np.ndarray, np.ndarray]:
    """(confidence, wrong by more than 2 px) of every valid ground-truth pixel of the scenes."""
    levels, wrong = [], []
    for scene in scenes:
        params = make_params(profile, {**values, "disparity_range": scene.disparity_range(), "near_detection": False})
        result = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True)
        assert scene.gt is not None and result.confidence is not None
        counted = np.isfinite(result.disparity) & evaluation_mask(scene.gt, scene.mask)
        levels.append(result.confidence[counted])
        wrong.append(np.abs(result.disparity[counted] - scene.gt[counted]) > 2.0)
    return np.concatenate(levels), np.concatenate(wrong)


def sparsification(args: argparse.Namespace) -> None:
    scenes = scenes_with_truth(args.scenes)
    print(f"{len(scenes)} scenes, each at its own disparity range; pixels pooled over the scenes")
    print("(kept: share of the valid, ground-truth pixels at or above the threshold; bad-2: of those kept)")
    pooled = {matcher: pooled_confidence(scenes, *run) for matcher, run in MATCHER_PROFILES.items()}
    print(table_header(("threshold", *(f"{m}: kept / bad-2" for m in pooled))))
    for threshold in THRESHOLDS:
        cells = [
            f"{(levels >= threshold).mean():.3f} / {wrong[levels >= threshold].mean():.4f}"
            for levels, wrong in pooled.values()
        ]
        print(table_row((f"{threshold:g}", *cells)))
    print(table_header(("matcher", "threshold keeping 80 %", "kept", "bad-2 of kept", "bad-2 of all valid", "ratio")))
    for matcher, (levels, wrong) in pooled.items():
        threshold = float(np.quantile(levels, 0.2))
        kept = levels >= threshold
        row = (matcher, f"{threshold:.3f}", f"{kept.mean():.3f}", f"{wrong[kept].mean():.4f}", f"{wrong.mean():.4f}")
        print(table_row((*row, times(wrong[kept].mean() / wrong.mean()))))


def too_near(args: argparse.Namespace) -> None:
    scenes = []
    for scene in scenes_with_truth(args.scenes):
        assert scene.gt is not None
        counted = evaluation_mask(scene.gt, scene.mask)
        if np.mean(scene.gt[counted] > args.range) >= 0.01:
            scenes.append(scene)
    names = ", ".join(scene.name for scene in scenes)
    print(f"{len(scenes)} scenes with ground truth beyond {args.range} px on 1 % or more of their pixels: {names}")
    print(f"disparity_range {args.range}; pixels pooled over the scenes")
    columns = ("profile", "near_detection", "beyond: valid", "within: density", "beyond: clearing rays")
    print(table_header((*columns, "strict beyond: valid", "strict within: density")))
    for profile in NEAR_PROFILES:
        for detection in (False, True):
            sums = np.zeros(7)
            for scene in scenes:
                params = make_params(profile, {"disparity_range": args.range, "near_detection": detection})
                disparity = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True).disparity
                assert scene.gt is not None
                counted, valid = evaluation_mask(scene.gt, scene.mask), np.isfinite(disparity)
                top = params.min_disparity + args.range
                beyond, within = counted & (scene.gt >= top + NEAR_MARGIN), counted & (scene.gt < top - NEAR_MARGIN)
                strict_beyond, strict_within = counted & (scene.gt >= top), counted & (scene.gt < top)
                with np.errstate(invalid="ignore"):
                    clearing = disparity < params.min_disparity + params.downsample  # as points2_clearing
                sums += [
                    beyond.sum(),
                    (beyond & valid).sum(),
                    (within & valid).sum() / within.sum(),
                    (beyond & clearing).sum(),
                    (strict_beyond & valid).sum() / strict_beyond.sum(),
                    (strict_within & valid).sum() / strict_within.sum(),
                    0,
                ]
            n = len(scenes)
            cells = (f"`{profile}`", str(detection).lower(), f"{sums[1] / sums[0]:.3f}", f"{sums[2] / n:.3f}")
            print(table_row((*cells, f"{int(sums[3])}", f"{sums[4] / n:.3f}", f"{sums[5] / n:.3f}")), flush=True)


def removed_pixels(args: argparse.Namespace) -> None:
    """What near_detection changes at each scene's own disparity range: the pixels it removes, and how the
    bad-2 of the estimated pixels follows from them (pooled counts: after = (bad before - bad removed) /
    (valid before - removed), when nothing is added)."""
    scenes = scenes_with_truth(args.scenes)
    print(f"{len(scenes)} scenes at their own disparity range; ground-truth pixels pooled over the scenes")
    columns = ("profile", "valid before", "bad-2 of est. before", "removed", "of them bad", "added")
    print(table_header((*columns, "bad-2 of est. after", "from the removed", "density before / after")))
    for profile in ("default", "quality"):
        sums = np.zeros(7)
        for scene in scenes:
            assert scene.gt is not None
            counted = evaluation_mask(scene.gt, scene.mask)
            runs = []
            for detection in (False, True):
                params = make_params(profile, {"disparity_range": scene.disparity_range(), "near_detection": detection})
                disparity = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True).disparity
                with np.errstate(invalid="ignore"):
                    runs.append((np.isfinite(disparity) & counted, np.abs(disparity - scene.gt) > 2.0))
            (before, bad_before), (after, bad_after) = runs
            removed = before & ~after
            sums += [
                counted.sum(),
                before.sum(),
                (before & bad_before).sum(),
                removed.sum(),
                (removed & bad_before).sum(),
                (after & ~before).sum(),
                (after & bad_after).sum(),
            ]
        total, valid, bad, removed_n, removed_bad, added, bad_after_n = sums
        predicted = (bad - removed_bad) / (valid - removed_n)
        cells = (f"`{profile}`", f"{int(valid)}", f"{bad / valid:.4f}", f"{int(removed_n)}", f"{int(removed_bad)}")
        after_cells = (f"{bad_after_n / (valid - removed_n + added):.4f}", f"{predicted:.4f}")
        density = f"{valid / total:.4f} / {(valid - removed_n + added) / total:.4f}"
        print(table_row((*cells, f"{int(added)}", *after_cells, density)), flush=True)


def check_cost(args: argparse.Namespace) -> None:
    """Medians of interleaved runs on one scene resized to 640x480, each matcher as its profile runs it
    (at its downsample): the match, the confidence read from its disparity and too-near detection."""
    keep_freed_memory()  # as StereoPipeline does: each frame's arrays reuse the last frame's pages
    scene = load_scene(args.scenes[0])
    left, right = (
        cv2.resize(to_grey8(image, 1.0), VGA, interpolation=cv2.INTER_AREA) for image in (scene.left, scene.right)
    )
    print(f"{scene.name} at {VGA[0]}x{VGA[1]}, 64 disparities, medians of {args.repeat} interleaved runs")
    cases: list[tuple[str, StereoParams]] = [
        ("sgbm (`default`)", make_params("default")),
        ("bm, OpenCV's (`fast`, 1/2 size)", make_params("fast")),
        ("bm, ours (`stereo_image_proc`)", make_params("stereo_image_proc")),
        ("census_sgm (`quality`)", make_params("quality")),
    ]
    prepared = []
    for name, params in cases:
        factor = params.downsample
        small = [
            cv2.resize(image, (VGA[0] // factor, VGA[1] // factor), interpolation=cv2.INTER_AREA)
            for image in (left, right)
        ]
        scaled = dataclasses.replace(params, downsample=1, disparity_range=max(16, params.disparity_range // factor))
        prepared.append((name, params.matcher, create_matcher(scaled), TooNearDetector(scaled), small))
    samples: dict[str, list[list[float]]] = {name: [[], [], []] for name, *_ in prepared}
    for run in range(args.repeat + 1):
        for name, matcher_name, matcher, detector, (small_left, small_right) in prepared:
            start = time.perf_counter()
            match = matcher.compute(small_left, small_right)
            matched = time.perf_counter()
            if match.confidence is None:
                neighbourhood_confidence(match.disparity, matcher_name)
            confident = time.perf_counter()
            detector.detect(small_left, small_right, match.disparity)
            detected = time.perf_counter()
            if run:  # the first: warm-up
                for series, value in zip(
                    samples[name], (matched - start, confident - matched, detected - confident), strict=True
                ):
                    series.append(value * 1000.0)
    print(table_header(("matcher", "match ms", "confidence ms", "vs match", "too-near detection ms", "vs match")))
    for name, (match_ms, confidence_ms, near_ms) in samples.items():
        m, c, d = (float(np.median(series)) for series in (match_ms, confidence_ms, near_ms))
        print(table_row((name, f"{m:.2f}", f"{c:.2f}", times(c / m), f"{d:.2f}", times(d / m))))


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
    questions.add_parser("sparsification", help="per matcher: confidence threshold against pixels kept and bad-2")
    near = questions.add_parser("too-near", help="pixels beyond the disparity range: valid, density, clearing rays")
    near.add_argument("--range", type=int, default=64)
    questions.add_parser("removed", help="near_detection at each scene's own range: pixels removed, bad-2 after")
    cost = questions.add_parser("check-cost", help="confidence and too-near detection time against the match's")
    cost.add_argument("--repeat", type=int, default=15)
    for question in questions.choices.values():
        question.add_argument("scenes", nargs="+", type=Path)
        question.add_argument("--markdown", action="store_true", help="(always markdown tables)")
    args = parse_bench_arguments(parser, "(always markdown tables)")
    questions_run = {
        "profiles": profiles,
        "confidence": confidence,
        "left-right": left_right,
        "sparsification": sparsification,
        "too-near": too_near,
        "removed": removed_pixels,
        "check-cost": check_cost,
    }
    questions_run[args.question](args)


if __name__ == "__main__":
    main()
