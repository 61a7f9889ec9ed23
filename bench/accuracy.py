"""Accuracy on scenes with ground truth: the profiles side by side, what the confidence is worth, what
the left-right check (disp12_max_diff) keeps, what the spatial filter gains, and what glare invalidation
removes from real recordings.

    .venv/bin/python bench/accuracy.py profiles SCENE_DIR... [--picture PATH] [--repeat 3] [--markdown]
    .venv/bin/python bench/accuracy.py confidence SCENE_DIR... [--profile quality] [--threshold 0.5]
    .venv/bin/python bench/accuracy.py left-right SCENE_DIR...
    .venv/bin/python bench/accuracy.py registration --data DIR [--profile default]
    .venv/bin/python bench/accuracy.py sparsification SCENE_DIR...
    .venv/bin/python bench/accuracy.py too-near SCENE_DIR... [--range 64]
    .venv/bin/python bench/accuracy.py removed SCENE_DIR...
    .venv/bin/python bench/accuracy.py check-cost SCENE_DIR [--repeat 15]
    .venv/bin/python bench/accuracy.py spatial SCENE_DIR... [--profiles default quality] [--picture PATH]
    .venv/bin/python bench/accuracy.py glare RECORDING... [--profile default] [--pictures DIR]

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

spatial: each profile without and with spatial_filter, means over the scenes: end-point error (of the
estimated pixels), bad-2, bad-2 of the estimated, density; --picture draws the first scene's strongest
depth edge (left | ground truth | without | with, enlarged). glare: per recording (a EuRoC folder of raw
frames with cam0_sensor.yaml and cam1_sensor.yaml, or a rectified scene folder) the share of the left
image that is glare, the share of it with a disparity without and with invalidate_saturated, and the
density outside it; --pictures draws each recording's first frame (rectified left with the glare in red |
disparity without | with).

profiles: each profile's mean bad-2, bad-2 of the estimated pixels, density and time per scene (the best
of --repeat), `default` first (the baseline of the ratio); --picture draws the first scene (left | ground
truth | each profile). Bundled scenes: test/data/scenes; larger sets (Middlebury, KITTI) are passed as
folders of scene folders, as `--data DIR` does for `make bench-docs`.

registration: depth registered to a colour camera, checked against ground truth. Each scene under DIR
with a right-view ground truth (disp_gt_right.png) is one frame through the frame stream, its right image
given again as the colour camera (rgb/image_raw + rgb/camera_info) with rgb_in_left the baseline along x;
the registered depth, as disparity, is compared with the right ground truth, on the right pixels the left
camera sees, beside the left disparity on the left pixels the right camera sees.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.confidence import neighbourhood_confidence
from stereo_depth.core.matching import create_matcher
from stereo_depth.core.memory import keep_freed_memory
from stereo_depth.core.metrics import Accuracy, accuracy, colorize_disparity, evaluation_mask, label
from stereo_depth.core.params import PROFILES, StereoParams, make_params
from stereo_depth.core.pipeline import StereoPipeline, StereoResult, to_grey8
from stereo_depth.core.saturation import rectified_glare, seen_in_right
from stereo_depth.core.too_near import TooNearDetector
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.scenes import Scene, load_scene, read_ground_truth

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row, times

DISP12_SETTINGS = (-1, 0, 1, 3)  # check off, stereo_image_proc's value, 1 and 3 px
# the calibration given to scenes without one: disparity is what is compared, so any focal length and
# baseline do
FOCAL_PX, BASELINE_M = 1000.0, 0.1
SEEN_PX = 1.0  # a pixel is seen by the other camera where both ground truths agree within this
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


def right_scenes(data: Path) -> list[Path]:
    found = sorted(path.parent for path in data.rglob("disp_gt_right.png"))
    if not found:
        raise SystemExit(f"ERROR: no scene under {data} has a right ground truth (disp_gt_right.png)")
    return found


def seen_by_other(gt: np.ndarray, other: np.ndarray, sign: int) -> np.ndarray:
    """The pixels of `gt`'s view that the other camera sees: the other view's ground truth at the pixel
    this one's disparity leads to (x - d from left to right: sign -1) agrees within SEEN_PX."""
    height, width = gt.shape
    rows, columns = np.mgrid[0:height, 0:width]
    valid = np.isfinite(gt)
    target = np.rint(columns + sign * np.where(valid, gt, 0)).astype(np.int64)
    inside = valid & (target >= 0) & (target < width)
    seen = np.zeros(gt.shape, bool)
    seen[inside] = np.abs(other[rows[inside], target[inside]] - gt[inside]) <= SEEN_PX
    return seen


def registered_disparity(scene: Scene, profile: str) -> tuple[np.ndarray, np.ndarray, float]:
    """(left disparity, the right camera's registered depth as disparity, registration ms) of one scene
    through the frame stream, the right image given again as the colour camera."""
    from stereo_depth.bag.types import rosbags_types
    from stereo_depth.core.camera import CameraInfo
    from stereo_depth.core.pose import Pose
    from stereo_depth.frames import FrameStream
    from stereo_depth.messages import array_to_image, camera_info_to_msg, make_header
    from stereo_depth.options import OutputOptions
    from stereo_depth.sync import StereoSet

    types = rosbags_types()
    height, width = scene.left.shape[:2]
    k = np.array([[FOCAL_PX, 0.0, width / 2.0], [0.0, FOCAL_PX, height / 2.0], [0.0, 0.0, 1.0]])
    infos = [
        CameraInfo.from_values(width, height, k, np.zeros(5), np.eye(3), np.hstack([k, [[offset], [0.0], [0.0]]]))
        for offset in (0.0, -FOCAL_PX * BASELINE_M, 0.0)  # left, right, the colour camera (the right one)
    ]
    header = make_header(types, 1, "left")
    colour_header = make_header(types, 1, "colour")
    left, right = (array_to_image(types, header, image) for image in (scene.left, scene.right))
    inputs = StereoSet(
        1, left, camera_info_to_msg(types, header, infos[0]), right, camera_info_to_msg(types, header, infos[1])
    )
    output = OutputOptions(rgb_in_left=Pose.from_list([BASELINE_M, 0, 0, 0, 0, 0, 1]))
    stream = FrameStream(
        types, make_params(profile, {"disparity_range": scene.disparity_range()}), output, rectified=True
    )
    stream.registration.add_colour(
        array_to_image(types, colour_header, scene.right), camera_info_to_msg(types, colour_header, infos[2])
    )
    out = stream.match(inputs, ())
    assert out.cloud is not None
    jobs = out.cloud.run().registered
    jobs[0].run(("depth_registered/image_rect",))  # loads the kernels
    messages, ms = jobs[0].run(("depth_registered/image_rect",))
    depth = np.frombuffer(bytes(messages["depth_registered/image_rect"].data), np.float32).reshape(height, width)
    with np.errstate(divide="ignore", invalid="ignore"):
        return out.disparity, (FOCAL_PX * BASELINE_M / depth).astype(np.float32), ms


def registration(args: argparse.Namespace) -> None:
    """Per scene: bad-2 over estimated pixels and density of the left disparity and of the registered depth."""
    print(f"profile `{args.profile}`; left: on the left pixels the right camera sees; registered: on the right")
    print("pixels the left camera sees (its depth as disparity, against the right ground truth):")
    columns = ("scene", "left bad-2 of est.", "registered bad-2 of est.", "difference", "left density")
    print(table_header((*columns, "registered density", "ratio", "registration ms")))
    for folder in right_scenes(args.data):
        scene = load_scene(folder)
        right_gt = read_ground_truth(folder, {**scene.calib, "gt_file": "disp_gt_right.png"})
        assert scene.gt is not None and right_gt is not None
        left, registered, ms = registered_disparity(scene, args.profile)
        mine = accuracy(left, scene.gt, seen_by_other(scene.gt, right_gt, -1))
        theirs = accuracy(registered, right_gt, seen_by_other(right_gt, scene.gt, 1))
        cells = (
            scene.name,
            f"{mine.bad2_est:.4f}",
            f"{theirs.bad2_est:.4f}",
            f"{theirs.bad2_est - mine.bad2_est:+.4f}",
            f"{mine.density:.3f}",
            f"{theirs.density:.3f}",
            times(theirs.density / mine.density),
            f"{ms:.1f}",
        )
        print(table_row(cells), flush=True)


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


def spatial(args: argparse.Namespace) -> None:
    scenes = scenes_with_truth(args.scenes)
    print(f"{len(scenes)} scenes with ground truth, means over scenes, without | with spatial_filter:")
    columns = ("profile", "end-point error", "ratio", "bad-2", "bad-2 of estimated", "density")
    print(table_header(columns))
    for profile in args.profiles:
        rows = []
        for scene in scenes:
            assert scene.gt is not None
            pair = [
                StereoPipeline(make_params(profile, {"disparity_range": scene.disparity_range(), "spatial_filter": on}))
                .match(scene.left, scene.right, None, rectified=True)
                .disparity
                for on in (False, True)
            ]
            if profile == args.profiles[0] and scene is scenes[0] and args.picture:
                edge_picture(scene, pair[0], pair[1], args.picture)
            rows.append([accuracy(disparity, scene.gt, scene.mask) for disparity in pair])
        off, on = ({k: float(np.mean([r[i].as_dict()[k] for r in rows])) for k in rows[0][0].as_dict()} for i in (0, 1))
        cells = (
            f"`{profile}`",
            f"{off['epe']:.4f} / {on['epe']:.4f}",
            times(on["epe"] / off["epe"]),
            f"{off['bad2']:.4f} / {on['bad2']:.4f}",
            f"{off['bad2_est']:.4f} / {on['bad2_est']:.4f}",
            f"{off['density']:.4f} / {on['density']:.4f}",
        )
        print(table_row(cells), flush=True)


def edge_picture(scene: Scene, without: np.ndarray, with_filter: np.ndarray, path: Path) -> None:
    """The 96x96 window holding the most ground-truth depth edge (steps over 2 px), enlarged 4x."""
    assert scene.gt is not None
    gt = np.nan_to_num(scene.gt)
    steps = (np.abs(np.diff(gt, axis=1, prepend=0)) > 2) | (np.abs(np.diff(gt, axis=0, prepend=0)) > 2)
    steps &= np.isfinite(scene.gt)
    size = 96
    density = cv2.boxFilter(steps.astype(np.float32), -1, (size, size), normalize=False)
    centres = density[size // 2 : -size // 2, size // 2 : -size // 2]  # windows inside the image, by top-left
    y, x = np.unravel_index(int(np.argmax(centres)), centres.shape)
    window = np.s_[y : y + size, x : x + size]
    top = float(np.nanmax(scene.gt[window]))
    images = [scene.left[window]] + [colorize_disparity(d[window], top) for d in (scene.gt, without, with_filter)]
    names = ("left", "ground truth", "without", "with spatial_filter")
    panels = [
        label(cv2.resize(i, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST), n)
        for i, n in zip(images, names, strict=True)
    ]
    write_picture(path, np.hstack(panels))


def write_picture(path: Path, image: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), image)
    print(f"picture: {path}", file=sys.stderr)


def recording_frames(folder: Path) -> tuple[list[tuple[np.ndarray, np.ndarray]], StereoCamera | None]:
    """A recording's pairs with its calibration: raw EuRoC frames (left/, right/, the sensor.yaml files), or
    a rectified scene (one pair, None)."""
    if not (folder / "cam0_sensor.yaml").is_file():
        scene = load_scene(folder)
        return [(scene.left, scene.right)], None
    camera = StereoCamera(*stereo_camera_infos(folder / "cam0_sensor.yaml", folder / "cam1_sensor.yaml"))
    names = sorted(path.name for path in (folder / "left").glob("*.png"))
    return [(read(folder / "left" / name), read(folder / "right" / name)) for name in names], camera


def read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"ERROR: cannot read {path}")
    return image


def glare(args: argparse.Namespace) -> None:
    print(
        f"profile `{args.profile}`; glare: the saturated textureless area of the left image, and the left pixels "
        "whose match lies in that of the right image; sums over all frames:"
    )
    columns = ("recording", "frames", "glare: left + seen in right", "valid in glare: off / on")
    print(table_header((*columns, "density outside: off / on", "drop")))
    for folder in args.recordings:
        pairs, camera = recording_frames(folder)
        pipelines = [StereoPipeline(make_params(args.profile, {"invalidate_saturated": on})) for on in (False, True)]
        level = pipelines[0].params.saturation_level
        counts = np.zeros(8)  # left glare, seen in right; glare, valid there off, on; outside, valid there off, on
        for index, (left, right) in enumerate(pairs):
            off, on = (p.match(left, right, camera, rectified=camera is None) for p in pipelines)
            shape = off.disparity.shape
            area = off.glare if off.glare is not None else np.zeros(shape, bool)
            right_glare = rectified_glare(right, None, camera, "right", shape, level)
            seen = seen_in_right(off.disparity, right_glare) & ~area if right_glare is not None else np.zeros_like(area)
            counts[:2] += (area.sum(), seen.sum())
            valid_off, valid_on = np.isfinite(off.disparity), np.isfinite(on.disparity)
            for k, pixels in enumerate((area | seen, ~(area | seen))):
                counts[2 + 3 * k : 5 + 3 * k] += (pixels.sum(), valid_off[pixels].sum(), valid_on[pixels].sum())
            if index == 0 and args.pictures:
                glare_picture(
                    args.pictures / f"glare_{folder.parent.name}_{folder.name}.png", off, on.disparity, area | seen
                )
        left_n, seen_n, glare_n, in_off, in_on, out_n, out_off, out_on = counts[0], *counts[1:]
        cells = (
            f"{folder.parent.name}/{folder.name}",
            len(pairs),
            f"{left_n / (glare_n + out_n):.4f} + {seen_n / (glare_n + out_n):.4f}",
            f"{in_off / max(glare_n, 1):.4f} / {in_on / max(glare_n, 1):.4f}",
            f"{out_off / out_n:.4f} / {out_on / out_n:.4f}",
            f"{(out_off - out_on) / out_n:.4f}",
        )
        print(table_row(cells), flush=True)


def glare_picture(path: Path, off: StereoResult, on: np.ndarray, area: np.ndarray) -> None:
    """Rectified left with the glare in red | disparity without | with invalidate_saturated, at half size."""
    marked = cv2.cvtColor(off.left_rect, cv2.COLOR_GRAY2BGR)
    marked[area] = (0.5 * marked[area] + (0, 0, 127)).astype(np.uint8)
    top = float(np.nanmax(off.disparity))
    images = (marked, colorize_disparity(off.disparity, top), colorize_disparity(on, top))
    names = ("rectified left, glare in red", "invalidate_saturated off", "invalidate_saturated on")
    half = (marked.shape[1] // 2, marked.shape[0] // 2)
    panels = [label(cv2.resize(i, half, interpolation=cv2.INTER_AREA), n) for i, n in zip(images, names, strict=True)]
    write_picture(path, np.hstack(panels))


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
    smoothed = questions.add_parser("spatial", help="each profile without and with spatial_filter")
    smoothed.add_argument("--profiles", nargs="+", choices=sorted(PROFILES), default=["default", "quality"])
    smoothed.add_argument("--picture", type=Path, help="draw the first scene's strongest depth edge here (PNG)")
    for question in questions.choices.values():
        question.add_argument("scenes", nargs="+", type=Path)
        question.add_argument("--markdown", action="store_true", help="(always markdown tables)")
    glared = questions.add_parser("glare", help="valid disparities in glare without and with invalidate_saturated")
    glared.add_argument("recordings", nargs="+", type=Path)
    glared.add_argument("--profile", choices=sorted(PROFILES), default="default")
    glared.add_argument("--pictures", type=Path, help="folder for one picture per recording (PNG)")
    glared.add_argument("--markdown", action="store_true", help="(always markdown tables)")
    registered = questions.add_parser("registration", help="registered depth against the right ground truth")
    registered.add_argument("--data", type=Path, required=True, help="searched for scenes with disp_gt_right.png")
    registered.add_argument("--profile", default="default", choices=sorted(PROFILES))
    registered.add_argument("--markdown", action="store_true", help="(always markdown tables)")
    args = parse_bench_arguments(parser, "(always markdown tables)")
    questions_run = {
        "profiles": profiles,
        "confidence": confidence,
        "left-right": left_right,
        "sparsification": sparsification,
        "too-near": too_near,
        "removed": removed_pixels,
        "check-cost": check_cost,
        "registration": registration,
        "spatial": spatial,
        "glare": glare,
    }
    questions_run[args.question](args)


if __name__ == "__main__":
    main()
