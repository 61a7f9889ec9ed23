"""Depth over time: flicker, ghost points, sporadic points and trails with and without the temporal filter.

Three kinds of sequence, each through the profile's pipeline and then `TemporalFilter` (what
`temporal_filter: true` runs, live and in `process`):

- static: a real scene with ground truth, the same view every frame with fresh sensor noise (Gaussian
  read/shot noise and a per-frame gain jitter per camera, as an auto-exposed camera shows);
- moving: a textured patch (cut from another real scene) at a known disparity in front of a real
  scene, moving sideways, then gone: how long its trail stays, and how much of it is seen while it moves;
- pitching: the rig turning about its baseline (plus and minus 2 degrees, 1.2 s period, 30 Hz), an exact
  homography of both rectified images of a real scene and of its ground truth, with fresh noise; once
  without odometry (the filter has to see the motion itself) and once with the rig's exact pose at each
  frame, as odometry gives it (`--pitching N`: the first N scenes);
- recorded: real static recordings (`--data DIR`: each folder in it a recording a real camera made
  standing still; README.md says how to build them): real sensor noise, auto-exposure and the errors
  that come back frame after frame; no ground truth.

Per row of the scenes: flicker (share of pixels whose valid / invalid state toggles between frames),
temporal std of the disparity (px, pixels valid in two or more frames), ghost points (valid, more than 2 px
from the ground truth, and lasting fewer than 3 frames; per frame, as a share of the pixels), bad-2 of
estimated, density, and the filter's ms per frame (median wall time, with the threads stereo_node gives
it: cpu_threads 0, this process's cores). Per recording: sporadic points (valid in fewer than 25 % of the
scored frames; counted per frame), jumps (pixels valid in two consecutive frames whose disparity changes
by more than 1 px; per frame) and density. A VGA row times the filter against the match on 640x480
frames of a scene, in the same run. Metrics skip the first `--warm-up` frames.

.venv/bin/python bench/temporal.py [--scenes DIR ...] [--data DIR] [--pitching 5] [--frames 30] [--seed 1]
    [--set temporal_delta=1.0 ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.bag.sources import read_frames
from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.params import StereoParams, make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.core.temporal import LONG_RUN, CameraMotion, Projection, TemporalFilter, TemporalSettings
from stereo_depth.core.threads import use_threads
from stereo_depth.formats.scenes import Scene, load_scene

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row

ROOT = Path(__file__).resolve().parent.parent
SCENES = sorted((ROOT / "test/data/scenes").iterdir())
NOISE_SIGMA = 2.0  # grey levels: read + shot noise of a machine-vision camera in good light
GAIN_JITTER = 0.01  # per frame and camera: auto-exposure / gain steps
FRAME_NS = 33_333_333  # 30 Hz
SPORADIC_SHARE = 0.25  # a pixel valid in fewer than this share of the frames is a sporadic point
JUMP_PX = 1.0  # a disparity change between consecutive frames larger than this is a jump
VGA = (640, 480)
VGA_FRAMES = 24
PITCH_DEGREES = 2.0  # the pitching rig: plus and minus this, about the baseline
PITCH_PERIOD_S = 1.2
PITCH_FRAMES = 72  # two periods at 30 Hz


# ------------------------------------------------------------------------------------------ sequences


def noisy(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    gain = 1.0 + GAIN_JITTER * rng.standard_normal()
    out = image.astype(np.float32) * np.float32(gain) + rng.normal(0.0, NOISE_SIGMA, image.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def static_sequence(scene: Scene, frames: int, seed: int) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    assert scene.gt is not None
    gt = np.where(scene.mask, scene.gt, np.nan) if scene.mask is not None else scene.gt
    for _ in range(frames):
        yield noisy(scene.left, rng), noisy(scene.right, rng), gt


def moving_sequence(
    scene: Scene, texture: np.ndarray, frames: int, vanish: int, seed: int
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """A patch of `texture` at a disparity above everything in the scene, moving right 4 px a frame,
    gone from frame `vanish` on. Ground truth: the patch's disparity on it, the scene's elsewhere, NaN
    where the patch hides a background pixel from the right camera."""
    rng = np.random.default_rng(seed)
    assert scene.gt is not None
    height, width = scene.gt.shape
    size = min(height, width) // 3
    patch = cv2.cvtColor(texture, cv2.COLOR_BGR2GRAY) if texture.ndim == 3 else texture
    patch = cv2.resize(patch[:size, :size], (size, size))
    patch = cv2.cvtColor(patch, cv2.COLOR_GRAY2BGR) if scene.left.ndim == 3 else patch
    d_obj = int(np.nanmax(scene.gt)) + 8
    top = (height - size) // 2
    cols = np.arange(width)[None, :]
    for k in range(frames):
        left, right, gt = scene.left.copy(), scene.right.copy(), scene.gt.copy()
        if k < vanish:
            x = d_obj + 4 + 4 * k
            left[top : top + size, x : x + size] = patch
            right[top : top + size, x - d_obj : x - d_obj + size] = patch
            rows = slice(top, top + size)
            seen_at = cols - gt[rows]  # where each background pixel of these rows lands in the right image
            hidden = (seen_at >= x - d_obj) & (seen_at < x - d_obj + size)
            gt[rows][hidden] = np.nan
            gt[top : top + size, x : x + size] = d_obj
        if scene.mask is not None:
            gt = np.where(scene.mask | (gt == d_obj), gt, np.nan)
        yield noisy(left, rng), noisy(right, rng), gt.astype(np.float32)


def pitch_rotation(index: int) -> np.ndarray:
    """The pitching rig's orientation at frame `index`: a turn about the baseline (the x axis)."""
    angle = np.radians(PITCH_DEGREES) * np.sin(2.0 * np.pi * index * FRAME_NS * 1e-9 / PITCH_PERIOD_S)
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def pitch_projection(scene: Scene) -> Projection:
    """The pinhole the pitching sequence is rendered with (focal length the image width, principal point
    the centre; the baseline any, as the motion is a turn about the camera centres)."""
    height, width = scene.left.shape[:2]
    f = float(width)
    return Projection(f, f, (width - 1) / 2.0, (height - 1) / 2.0, f * 0.1, 0.0)


def pitch_homography(scene: Scene, index: int) -> np.ndarray:
    """The image motion of frame `index`: H = K R^T K^-1, a first-frame pixel to this frame's."""
    projection = pitch_projection(scene)
    k = np.array([[projection.fx, 0.0, projection.cx], [0.0, projection.fy, projection.cy], [0.0, 0.0, 1.0]])
    return np.asarray(k @ pitch_rotation(index).T @ np.linalg.inv(k))


def anchored_to_scene(scene: Scene, disparities: list[np.ndarray], first: int) -> list[np.ndarray]:
    """Frames first, first + 1, ... of a pitching sequence mapped back to the first frame's view (nearest
    pixel, disparities scaled back to that view): a point of the scene keeps its pixel, so its runs of
    frames are the scene point's, not a pixel's the view slides over."""
    height, width = disparities[0].shape
    projection = pitch_projection(scene)
    rows = ((np.arange(height, dtype=np.float64)[:, None] - projection.cy) / projection.fy).astype(np.float32)
    out = []
    for offset, disparity in enumerate(disparities):
        rotation = pitch_rotation(first + offset)
        back = cv2.warpPerspective(
            disparity.astype(np.float32),
            pitch_homography(scene, first + offset),
            (width, height),
            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=float("nan"),
        )
        out.append(back * (np.float32(rotation[1, 1]) - np.float32(rotation[2, 1]) * rows))
    return out


def pitching_motions(scene: Scene, frames: int) -> list[CameraMotion]:
    """The odometry of the pitching rig: the camera's exact pose at each frame."""
    projection = pitch_projection(scene)
    motions = []
    for index in range(frames):
        pose = np.eye(4)
        pose[:3, :3] = pitch_rotation(index)
        motions.append(CameraMotion(pose, projection))
    return motions


def pitching_sequence(scene: Scene, frames: int, seed: int) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The rig pitching about its baseline (PITCH_DEGREES, PITCH_PERIOD_S, 30 Hz): a rotation about the
    axis through both camera centres, so both rectified images move by the same homography H = K R^T K^-1
    (K: `pitch_projection`; any pinhole K is exact) and stay rectified. The ground truth moves with them:
    a point's disparity scales by Z / Z' = 1 / (R^T K^-1 p)_z."""
    rng = np.random.default_rng(seed)
    assert scene.gt is not None
    height, width = scene.gt.shape
    projection = pitch_projection(scene)
    gt = np.where(scene.mask, scene.gt, np.nan) if scene.mask is not None else scene.gt
    rows = (np.arange(height, dtype=np.float64)[:, None] - projection.cy) / projection.fy
    for index in range(frames):
        rotation = pitch_rotation(index)
        c, s = rotation[1, 1], rotation[2, 1]
        h = pitch_homography(scene, index)
        scaled = (gt / (c - s * rows)).astype(np.float32)  # the disparity each source pixel has after the turn
        size = (width, height)
        moved_gt = cv2.warpPerspective(
            scaled, h, size, flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan")
        )
        left, right = (
            cv2.warpPerspective(image, h, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            for image in (scene.left, scene.right)
        )
        yield noisy(left, rng), noisy(right, rng), moved_gt


# ------------------------------------------------------------------------------------------ metrics


@dataclasses.dataclass
class Row:
    flicker: float
    temporal_std: float
    ghosts: float
    bad2_est: float
    density: float
    ms: float


def metrics(disparities: list[np.ndarray], gts: list[np.ndarray] | None, ms: float) -> Row:
    """The row's numbers; without ground truth (None) every pixel counts and ghosts and bad-2 are NaN."""
    d = np.stack(disparities)
    gt = np.stack(gts) if gts is not None else np.zeros(d.shape, np.float32)
    counted = np.isfinite(gt)
    valid = np.isfinite(d) & counted
    flicker = float((valid[1:] != valid[:-1])[counted[1:] & counted[:-1]].mean())
    n_valid = valid.sum(axis=0)
    with np.errstate(invalid="ignore"):
        values = np.where(valid, d, np.nan)
        std = np.nanstd(values[:, n_valid >= 2], axis=0)
    bad = valid & (np.abs(np.where(valid, d, 0) - np.where(counted, gt, 0)) > 2.0)
    ghosts = short_runs(bad, 3).sum() / max(1, counted.sum())
    estimated = max(1, int(valid.sum()))
    no_gt = float("nan") if gts is None else 1.0
    return Row(
        flicker=flicker,
        temporal_std=float(np.mean(std)) if std.size else float("nan"),
        ghosts=float(ghosts) * no_gt,
        bad2_est=float(bad.sum() / estimated) * no_gt,
        density=float(valid.sum() / max(1, counted.sum())),
        ms=ms,
    )


def short_runs(flags: np.ndarray, shorter_than: int) -> np.ndarray:
    """Per frame and pixel: True inside a run of consecutive True frames shorter than `shorter_than`
    that ends before the sequence does (a run cut off by the end has an unknown length)."""
    frames = flags.shape[0]
    out = np.zeros_like(flags)
    run = np.zeros(flags.shape[1:], np.int32)
    for t in range(frames + 1):
        current = flags[t] if t < frames else np.zeros_like(flags[0])
        ended = (run > 0) & ~current & (t < frames)
        for back in range(1, shorter_than):
            mark = ended & (run == back)
            for j in range(1, back + 1):
                out[t - j][mark] = True
        run = np.where(current, run + 1, 0)
    return out


def run(
    pipeline: StereoPipeline,
    frames: Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]],
    settings: TemporalSettings | None,
    camera: StereoCamera | None,
    warm_up: int,
    motions: list[CameraMotion] | None = None,
) -> tuple[list[np.ndarray], list[np.ndarray], float]:
    """Disparities (filtered when `settings`), ground truths and the filter's median ms per frame;
    `motions`: each frame's odometry (None: none)."""
    outs, gts, filter_ms, _ = timed_run(pipeline, frames, settings, camera, warm_up, motions)
    return outs, gts, filter_ms


def timed_run(
    pipeline: StereoPipeline,
    frames: Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]],
    settings: TemporalSettings | None,
    camera: StereoCamera | None,
    warm_up: int,
    motions: list[CameraMotion] | None = None,
) -> tuple[list[np.ndarray], list[np.ndarray], float, float]:
    """`run`, and the match's median ms per frame (rectify and match, the stage the filter follows)."""
    temporal = TemporalFilter()
    outs, gts, times, match_times = [], [], [], []
    for k, (left, right, gt) in enumerate(frames):
        start = time.perf_counter()
        result = pipeline.match(left, right, camera, rectified=camera is None)
        match_times.append((time.perf_counter() - start) * 1000.0)
        disparity = result.disparity
        if settings is not None:
            start = time.perf_counter()  # wall: the kernel runs on numba's threads
            motion = None if motions is None else motions[k]
            disparity = temporal.apply(
                disparity, result.confidence, k * FRAME_NS, 0, settings, view=result.left_rect, motion=motion
            )
            if k >= warm_up:
                times.append((time.perf_counter() - start) * 1000.0)
        if k >= warm_up:
            outs.append(disparity)
            gts.append(gt)
    median = lambda values: float(np.median(values)) if values else 0.0  # noqa: E731
    return outs, gts, median(times), median(match_times)


MARKDOWN_COLUMNS = (
    "sequence",
    "profile",
    "flicker, on / off",
    "ghost points, on / off",
    "bad-2 of estimated, on - off",
    "density, on - off",
    "ms",
)


def header(markdown: bool) -> None:
    if markdown:
        print(table_header(MARKDOWN_COLUMNS))
        return
    print(
        f"{'sequence':28s}{'profile':9s}{'filter':6s}{'flicker':>9s}{'t-std':>9s}{'ghosts':>10s}"
        f"{'bad2est':>9s}{'density':>9s}{'ms':>8s}"
    )


def report(name: str, profile: str, off: Row, on: Row, markdown: bool) -> None:
    """One sequence without and with the filter: two rows, or one markdown row of on/off comparisons."""
    if markdown:
        ratio = lambda a, b: f"{a / b:.2f}" if b > 0 else "-"  # noqa: E731
        cells = (name, f"`{profile}`", ratio(on.flicker, off.flicker), ratio(on.ghosts, off.ghosts))
        bad2 = "-" if np.isnan(on.bad2_est) else f"{on.bad2_est - off.bad2_est:+.4f}"
        print(table_row((*cells, bad2, f"{on.density - off.density:+.3f}", f"{on.ms:.1f}")))
        return
    for label, row in (("off", off), ("on", on)):
        print(
            f"{name:28s}{profile:9s}{label:6s}{row.flicker:9.4f}{row.temporal_std:9.3f}{row.ghosts:10.5f}"
            f"{row.bad2_est:9.4f}{row.density:9.4f}{row.ms:8.2f}"
        )


def trail_frames(disparities: list[np.ndarray], gts: list[np.ndarray], vanish: int, d_obj: float) -> int:
    """Frames from the patch's disappearance until no pixel shows its disparity (within 2 px) where the
    ground truth is the scene behind it."""
    for k in range(vanish, len(disparities)):
        d, gt = disparities[k], gts[k]
        with np.errstate(invalid="ignore"):
            ghost = (np.abs(d - d_obj) <= 2.0) & (np.abs(gt - d_obj) > 2.0)
        if not ghost.any():
            return k - vanish
    return len(disparities) - vanish


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", type=Path, default=SCENES)
    parser.add_argument(
        "--data", type=Path, help="a folder of static recordings, one folder each (bench/README.md: how to build)"
    )
    parser.add_argument("--profiles", nargs="+", default=["default", "quality"])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--warm-up", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1, help="the static sequences' noise (a second seed: the spread)")
    parser.add_argument(
        "--pitching", type=int, default=5, metavar="N", help="the pitching rig on the first N scenes (0: none)"
    )
    parser.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE", help="temporal_* options")
    args = parse_bench_arguments(parser)
    values = dict(item.split("=", 1) for item in args.set)
    settings = make_params("default", {"temporal_filter": "true", **values}).temporal
    threads = use_threads(0)  # stereo_node's default (cpu_threads 0)
    print(
        f"temporal filter: {settings}; {args.frames} frames a sequence, the first {args.warm_up} not scored; "
        f"{threads} threads"
    )
    header(args.markdown)
    summary: dict[str, list[tuple[Row, Row]]] = {}
    scenes = [load_scene(path) for path in args.scenes]
    for profile in args.profiles:
        for scene in scenes:
            params = make_params(profile, {"disparity_range": scene.disparity_range()})
            rows = []
            for chosen in (None, settings):
                pipeline = StereoPipeline(params)
                outs, gts, ms = run(
                    pipeline, static_sequence(scene, args.frames, args.seed), chosen, None, args.warm_up
                )
                rows.append(metrics(outs, gts, ms))
            report(f"static {scene.name}", profile, rows[0], rows[1], args.markdown)
            summary.setdefault(profile, []).append((rows[0], rows[1]))
    notes = []
    texture = scenes[-1].left
    for profile in args.profiles:
        scene = scenes[0]
        vanish = args.frames - 8
        d_obj = float(int(np.nanmax(scene.gt)) + 8) if scene.gt is not None else 0.0
        params = make_params(profile, {"disparity_range": -(-int(d_obj + 16) // 16) * 16})
        rows = []
        for chosen in (None, settings):
            pipeline = StereoPipeline(params)
            frames = moving_sequence(scene, texture, args.frames, vanish, 2)
            outs, gts, ms = run(pipeline, frames, chosen, None, 0)
            rows.append(metrics(outs[args.warm_up :], gts[args.warm_up :], ms))
            moving = zip(outs[args.warm_up : vanish], gts[args.warm_up : vanish], strict=True)
            on_patch = [np.isfinite(d[np.abs(g - d_obj) < 0.5]).mean() for d, g in moving]
            notes.append(
                f"moving {scene.name}, {profile}, filter {'on' if chosen else 'off'}: trail gone "
                f"{trail_frames(outs, gts, vanish, d_obj)} frames after the patch vanished; patch seen while "
                f"moving: {np.mean(on_patch):.3f} of its pixels"
            )
        report(f"moving {scene.name}", profile, rows[0], rows[1], args.markdown)
    pitching: dict[str, list[tuple[Row, Row]]] = {}
    odometry: dict[str, list[tuple[Row, Row]]] = {}
    for profile in args.profiles:
        for scene in scenes[: args.pitching]:
            params = make_params(profile, {"disparity_range": scene.disparity_range()})
            off = pitching_metrics(scene, params, None, None, args)
            for motions, table, label in (
                (None, pitching, "pitching"),
                (pitching_motions(scene, PITCH_FRAMES), odometry, "pitching, odometry"),
            ):
                on = pitching_metrics(scene, params, settings, motions, args)
                report(f"{label} {scene.name}", profile, off, on, args.markdown)
                table.setdefault(profile, []).append((off, on))
    for profile in args.profiles:
        vga_cost(profile, settings, scenes[0], args.markdown)
    recorded = recordings(args.data, args.profiles, settings, args.warm_up, args.markdown) if args.data else []
    print()
    for kind, worst in (("static", summary), ("pitching (no odometry)", pitching), ("pitching (odometry)", odometry)):
        for profile, pairs in worst.items():
            print(worst_of(kind, profile, pairs))
    for note in notes:
        print(note)
    for line in recorded:
        print(line)


def pitching_metrics(
    scene: Scene,
    params: StereoParams,
    settings: TemporalSettings | None,
    motions: list[CameraMotion] | None,
    args: argparse.Namespace,
) -> Row:
    """A pitching sequence's row, counted in the scene's frame (`anchored_to_scene`): on a moving rig a
    ghost is a point that lasts fewer than 3 frames at one place in the scene; a wrong match that stays
    on the edge it came from while the view moves is a steady error, which bad-2 counts."""
    frames = pitching_sequence(scene, PITCH_FRAMES, args.seed)
    outs, gts, ms = run(StereoPipeline(params), frames, settings, None, args.warm_up, motions)
    return metrics(anchored_to_scene(scene, outs, args.warm_up), anchored_to_scene(scene, gts, args.warm_up), ms)


def worst_of(kind: str, profile: str, pairs: list[tuple[Row, Row]]) -> str:
    """The summary line of one kind of sequence: each figure's worst scene, filter on against off."""
    worst_flicker = max(on.flicker / max(off.flicker, 1e-9) for off, on in pairs)
    worst_ghosts = max(on.ghosts / max(off.ghosts, 1e-9) for off, on in pairs)
    worst_bad2 = max(on.bad2_est - off.bad2_est for off, on in pairs)
    worst_density = min(on.density - off.density for off, on in pairs)
    return (
        f"{kind}, {profile}, worst scene of {len(pairs)}: flicker on/off {worst_flicker:.3f}, ghosts on/off "
        f"{worst_ghosts:.3f}, bad-2 of estimated on-off {worst_bad2:+.4f}, density on-off {worst_density:+.4f}"
    )


def vga_cost(profile: str, settings: TemporalSettings, scene: Scene, markdown: bool) -> None:
    """The filter's and the match's ms per 640x480 frame, in the same run, on real disparities (and
    confidences) of the profile's matcher: the scene scaled to VGA, with fresh noise every frame; still,
    and pitching with odometry (every remembered frame moved; timed once the history is full)."""
    assert scene.gt is not None
    vga = dataclasses.replace(
        scene,
        left=cv2.resize(scene.left, VGA),
        right=cv2.resize(scene.right, VGA),
        gt=cv2.resize(scene.gt, VGA, interpolation=cv2.INTER_NEAREST) * np.float32(VGA[0] / scene.left.shape[1]),
        mask=None,
        calib={},  # the range from the scaled ground truth
    )
    params = make_params(profile, {"disparity_range": vga.disparity_range()})
    for label, frames, motions, warm_up in (
        ("time only", static_sequence(vga, VGA_FRAMES, 3), None, 0),
        (
            "pitching, odometry",
            pitching_sequence(vga, LONG_RUN + VGA_FRAMES, 3),
            pitching_motions(vga, LONG_RUN + VGA_FRAMES),
            LONG_RUN,
        ),
    ):
        _, _, filter_ms, match_ms = timed_run(StereoPipeline(params), frames, settings, None, warm_up, motions)
        cost = f"{filter_ms:.1f} ms = {filter_ms / match_ms:.3f}x the match ({match_ms:.0f} ms)"
        if markdown:
            print(table_row((f"640x480 (VGA) {scene.name}, {label}", f"`{profile}`", "-", "-", "-", "-", cost)))
        else:
            print(f"{'640x480 (VGA), ' + label:28s}{profile:9s}{'on':6s}{cost}")


@dataclasses.dataclass
class RecordedRow:
    sporadic: float  # per frame
    jumps: float  # per frame
    density: float


def recorded_metrics(disparities: list[np.ndarray]) -> RecordedRow:
    """Sporadic points, jumps and density of a recording's scored frames (no ground truth)."""
    d = np.stack(disparities)
    valid = np.isfinite(d)
    share = valid.mean(axis=0)
    sporadic = valid & (share < SPORADIC_SHARE)[None]
    both = valid[1:] & valid[:-1]
    with np.errstate(invalid="ignore"):
        jumps = both & (np.abs(d[1:] - d[:-1]) > JUMP_PX)
    return RecordedRow(
        sporadic=float(sporadic.sum() / len(d)),
        jumps=float(jumps.sum() / max(1, len(d) - 1)),
        density=float(valid.mean()),
    )


def recordings(data: Path, profiles: list[str], settings: TemporalSettings, warm_up: int, markdown: bool) -> list[str]:
    """Each recording in `data` through each profile, filter off and on; rows, then summary lines."""
    folders = sorted(path for path in data.iterdir() if path.is_dir())
    if not folders:
        msg = f"{data}: no recording folders in it (bench/README.md says how to build them)"
        raise SystemExit(msg)
    if markdown:
        print(
            table_header(
                ("recording", "profile", "frames", "sporadic points, on / off", "jumps, on / off", "density, off -> on")
            )
        )
    summary = []
    for profile in profiles:
        worst = {"sporadic": 0.0, "jumps": 0.0, "density": 0.0}
        for folder in folders:
            frames = list(read_frames([folder]))
            pipeline = StereoPipeline(make_params(profile))
            camera = (
                None if frames[0].left_info is None else pipeline.camera_for(frames[0].left_info, frames[0].right_info)
            )
            rows = []
            for chosen in (None, settings):
                sequence = ((f.left, f.right, np.zeros(f.left.shape[:2], np.float32)) for f in frames)
                outs, _, _ = run(pipeline, sequence, chosen, camera, warm_up)
                rows.append(recorded_metrics(outs))
            off, on = rows
            sporadic, jumps = on.sporadic / max(off.sporadic, 1e-9), on.jumps / max(off.jumps, 1e-9)
            worst["sporadic"] = max(worst["sporadic"], sporadic)
            worst["jumps"] = max(worst["jumps"], jumps)
            worst["density"] = min(worst["density"], on.density - off.density)
            cells = (
                f"{sporadic:.2f} ({on.sporadic:,.0f} / {off.sporadic:,.0f})",
                f"{jumps:.3f} ({on.jumps:,.0f} / {off.jumps:,.0f})",
                f"{off.density:.3f} -> {on.density:.3f}",
            )
            if markdown:
                print(table_row((folder.name, f"`{profile}`", len(frames) - warm_up, *cells)))
            else:
                print(f"{folder.name:28s}{profile:9s}{len(frames) - warm_up:5d}  " + "  ".join(cells))
        summary.append(
            f"recorded, {profile}, worst of {len(folders)}: sporadic points on/off {worst['sporadic']:.3f}, "
            f"jumps on/off {worst['jumps']:.3f}, density on-off {worst['density']:+.4f}"
        )
    return summary


if __name__ == "__main__":
    main()
