"""Accuracy on scenes with ground truth: the profiles side by side, what the confidence is worth, what
the left-right check (disp12_max_diff) keeps, what the spatial filter gains, and what glare invalidation
removes from real recordings.

    .venv/bin/python bench/accuracy.py profiles SCENE_DIR... [--picture PATH] [--repeat 3] [--markdown]
    .venv/bin/python bench/accuracy.py confidence SCENE_DIR... [--profile quality] [--threshold 0.5]
    .venv/bin/python bench/accuracy.py left-right SCENE_DIR...
    .venv/bin/python bench/accuracy.py spatial SCENE_DIR... [--profiles default quality] [--picture PATH]
    .venv/bin/python bench/accuracy.py glare RECORDING... [--profile default] [--pictures DIR]

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
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.metrics import Accuracy, accuracy, colorize_disparity, label
from stereo_depth.core.params import PROFILES, make_params
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.core.saturation import rectified_glare, seen_in_right
from stereo_depth.formats.euroc import stereo_camera_infos
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
    smoothed = questions.add_parser("spatial", help="each profile without and with spatial_filter")
    smoothed.add_argument("--profiles", nargs="+", choices=sorted(PROFILES), default=["default", "quality"])
    smoothed.add_argument("--picture", type=Path, help="draw the first scene's strongest depth edge here (PNG)")
    for question in questions.choices.values():
        question.add_argument("scenes", nargs="+", type=Path)
    glared = questions.add_parser("glare", help="valid disparities in glare without and with invalidate_saturated")
    glared.add_argument("recordings", nargs="+", type=Path)
    glared.add_argument("--profile", choices=sorted(PROFILES), default="default")
    glared.add_argument("--pictures", type=Path, help="folder for one picture per recording (PNG)")
    for question in questions.choices.values():
        question.add_argument("--markdown", action="store_true", help="(always markdown tables)")
    args = parse_bench_arguments(parser, "(always markdown tables)")
    answers = {"profiles": profiles, "confidence": confidence, "left-right": left_right, "spatial": spatial}
    {**answers, "glare": glare}[args.question](args)


if __name__ == "__main__":
    main()
