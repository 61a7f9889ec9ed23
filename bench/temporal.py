"""Depth over time: flicker, ghost points and trails with and without the temporal filter.

Three kinds of sequence, each through the profile's pipeline and then `TemporalFilter` (what
`temporal_filter: true` runs, live and in `process`):

- static: a real scene with ground truth, the same view every frame with fresh sensor noise (Gaussian
  read/shot noise and a per-frame gain jitter per camera, as an auto-exposed camera shows);
- moving: a textured patch (cut from another real scene) at a known disparity in front of a real
  scene, moving sideways, then gone: how long its trail stays, and how much of it is seen while it moves;
- euroc: the bundled EuRoC frames (a real moving camera, raw and distorted; no ground truth).

Per row: flicker (share of pixels whose valid / invalid state toggles between frames), temporal std of
the disparity (px, pixels valid in two or more frames), ghost points (valid, more than 2 px from the
ground truth, and lasting fewer than 3 frames; per frame, as a share of the pixels), bad-2 of
estimated, density, and the filter's ms per frame (median wall time, with the threads stereo_node gives
it: cpu_threads 0, this process's cores; the euroc rows are 752x480, more than VGA, and a VGA row
times 640x480 crops of them). Metrics skip the first `--warm-up` frames.

.venv/bin/python bench/temporal.py [--scenes DIR ...] [--frames 30] [--seed 1] [--set temporal_delta=1.0 ...]
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

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.core.temporal import TemporalFilter, TemporalSettings
from stereo_depth.core.threads import use_threads
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.scenes import Scene, load_scene

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row

ROOT = Path(__file__).resolve().parent.parent
SCENES = sorted((ROOT / "test/data/scenes").iterdir())
EUROC = ROOT / "test/data/euroc"
NOISE_SIGMA = 2.0  # grey levels: read + shot noise of a machine-vision camera in good light
GAIN_JITTER = 0.01  # per frame and camera: auto-exposure / gain steps
FRAME_NS = 33_333_333  # 30 Hz


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
) -> tuple[list[np.ndarray], list[np.ndarray], float]:
    """Disparities (filtered when `settings`), ground truths and the filter's mean ms per frame."""
    temporal = TemporalFilter()
    outs, gts, times = [], [], []
    for k, (left, right, gt) in enumerate(frames):
        result = pipeline.match(left, right, camera, rectified=camera is None)
        disparity = result.disparity
        if settings is not None:
            start = time.perf_counter()  # wall: the kernel runs on numba's threads
            disparity = temporal.apply(disparity, result.confidence, k * FRAME_NS, 0, settings)
            times.append((time.perf_counter() - start) * 1000.0)
        if k >= warm_up:
            outs.append(disparity)
            gts.append(gt)
    return outs, gts, float(np.median(times)) if times else 0.0


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
    parser.add_argument("--profiles", nargs="+", default=["default", "quality"])
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--warm-up", type=int, default=8)
    parser.add_argument("--seed", type=int, default=1, help="the static sequences' noise (a second seed: the spread)")
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
    euroc(args.profiles, settings, args.markdown)
    print()
    for profile, pairs in summary.items():
        worst_flicker = max(on.flicker / max(off.flicker, 1e-9) for off, on in pairs)
        worst_ghosts = max(on.ghosts / max(off.ghosts, 1e-9) for off, on in pairs)
        worst_bad2 = max(on.bad2_est - off.bad2_est for off, on in pairs)
        worst_density = min(on.density - off.density for off, on in pairs)
        print(
            f"static, {profile}, worst scene of {len(pairs)}: flicker on/off {worst_flicker:.3f}, ghosts on/off "
            f"{worst_ghosts:.3f}, bad-2 of estimated on-off {worst_bad2:+.4f}, density on-off {worst_density:+.4f}"
        )
    for note in notes:
        print(note)


def grey(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert image is not None, path
    return image


VGA_REPEATS = 4  # the EuRoC frames, cropped, looped: 24 frames to time


def euroc(profiles: list[str], settings: TemporalSettings, markdown: bool) -> None:
    """The bundled EuRoC frames (raw, distorted, 752x480, 0.6 s apart): no ground truth, so flicker,
    density and time only; then the filter's time on their rectified 640x480 (VGA) crops."""
    left_info, right_info = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    names = sorted(path.name for path in (EUROC / "left").glob("*.png"))
    images = [(grey(EUROC / "left" / n), grey(EUROC / "right" / n)) for n in names]
    for profile in profiles:
        vga_ms(profile, settings, [(left[:, :640], right[:, :640]) for left, right in images], markdown)
    for profile in profiles:
        pipeline = StereoPipeline(make_params(profile))
        camera = pipeline.camera_for(left_info, right_info)
        rows = []
        for chosen in (None, settings):
            frames = ((left, right, np.zeros(left.shape, np.float32)) for left, right in images)
            outs, _, ms = run(pipeline, frames, chosen, camera, 0)
            rows.append(metrics(outs, None, ms))
        report(f"EuRoC, {len(images)} frames 0.6 s apart", profile, rows[0], rows[1], markdown)


def vga_ms(
    profile: str, settings: TemporalSettings, images: list[tuple[np.ndarray, np.ndarray]], markdown: bool
) -> None:
    """The filter's ms per 640x480 frame (the issue's budget: 2 ms), on real disparities (and
    confidences) of the profile's matcher; the pairs are matched as rectified."""
    pipeline = StereoPipeline(make_params(profile))
    frames = ((left, right, np.zeros(left.shape, np.float32)) for left, right in images * VGA_REPEATS)
    _, _, ms = run(pipeline, frames, settings, None, 0)
    if markdown:
        print(table_row(("640x480 (VGA), time only", f"`{profile}`", "-", "-", "-", "-", f"{ms:.1f}")))
    else:
        print(f"{'640x480 (VGA), time only':28s}{profile:9s}{'on':6s}{'':45s}{ms:8.2f}")


if __name__ == "__main__":
    main()
