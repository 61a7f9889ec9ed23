"""Per-stage time of StereoPipeline for each profile, against the bare OpenCV calls for the same work
(profiles that downsample or fill holes have no bare equivalent: their ratio column shows '-').

Real raw EuRoC pairs (test/data/euroc) resized to each resolution, calibration scaled with them. The
bare baseline does what a hand-written OpenCV script would: remap x2, the matcher, reprojectImageTo3D.
Both run in the same process, interleaved, and the table gives medians and the ratio ours / bare.

    .venv/bin/python bench/pipeline_stages.py [--repeat 20] [--profiles default fast stereo_image_proc]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.core.matching import Matcher, create_matcher
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import STAGES, StereoPipeline
from stereo_depth.euroc import stereo_camera_infos

EUROC = Path(__file__).resolve().parents[1] / "test" / "data" / "euroc"
RESOLUTIONS = ((640, 480), (1280, 720))


def scaled_info(info: CameraInfo, width: int, height: int) -> CameraInfo:
    sx, sy = width / info.width, height / info.height
    scale = np.diag([sx, sy, 1.0])
    return dataclasses.replace(info, width=width, height=height, k=scale @ info.k, p=scale @ info.p)


def load_pair(width: int, height: int) -> tuple[np.ndarray, np.ndarray, StereoCamera]:
    name = sorted((EUROC / "left").glob("*.png"))[0].name
    left = cv2.resize(cv2.imread(str(EUROC / "left" / name), cv2.IMREAD_GRAYSCALE), (width, height))
    right = cv2.resize(cv2.imread(str(EUROC / "right" / name), cv2.IMREAD_GRAYSCALE), (width, height))
    info_l, info_r = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    return left, right, StereoCamera(scaled_info(info_l, width, height), scaled_info(info_r, width, height))


def bare_opencv(left: np.ndarray, right: np.ndarray, camera: StereoCamera, matcher: Matcher) -> float:
    """The same work written directly against OpenCV (maps prebuilt, as any careful script would)."""
    start = time.perf_counter()
    ml, mr = camera.rectification_maps("left"), camera.rectification_maps("right")
    rl = cv2.remap(left, ml[0], ml[1], cv2.INTER_LINEAR)
    rr = cv2.remap(right, mr[0], mr[1], cv2.INTER_LINEAR)
    disparity = matcher.compute(rl, rr).disparity
    cv2.reprojectImageTo3D(disparity, camera.q)
    return (time.perf_counter() - start) * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--profiles", nargs="+", default=["default", "fast", "stereo_image_proc"])
    parser.add_argument("--disparity-range", type=int, default=64)
    args = parser.parse_args()
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, disparity_range {args.disparity_range}")
    header = f"{'profile':18s}{'size':>10s}" + "".join(f"{s:>9s}" for s in STAGES)
    print(header + f"{'total':>9s}{'bare cv':>9s}{'ratio':>7s}")
    for width, height in RESOLUTIONS:
        left, right, camera = load_pair(width, height)
        for profile in args.profiles:
            params = make_params(profile, {"disparity_range": args.disparity_range})
            pipeline = StereoPipeline(params)
            same_work = params.downsample == 1 and not params.fill_holes
            bare_matcher = create_matcher(params)
            stages: dict[str, list[float]] = {s: [] for s in STAGES}
            totals, bare = [], []
            for _ in range(args.repeat + 2):
                start = time.perf_counter()
                result = pipeline.process(left, right, camera)
                totals.append((time.perf_counter() - start) * 1000.0)
                for s in STAGES:
                    stages[s].append(result.timings_ms[s])
                if same_work:
                    bare.append(bare_opencv(left, right, camera, bare_matcher))
            med = {s: statistics.median(v[2:]) for s, v in stages.items()}
            total = statistics.median(totals[2:])
            row = f"{profile:18s}{f'{width}x{height}':>10s}" + "".join(f"{med[s]:9.1f}" for s in STAGES)
            if same_work:
                bare_ms = statistics.median(bare[2:])
                row += f"{total:9.1f}{bare_ms:9.1f}{total / bare_ms:7.2f}"
            else:  # downsampling / hole filling: no bare OpenCV call does the same work
                row += f"{total:9.1f}{'-':>9s}{'-':>7s}"
            print(row, flush=True)


if __name__ == "__main__":
    main()
