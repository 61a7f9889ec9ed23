"""Per-stage time of stereo_node's work for each profile, against the bare OpenCV calls for the same work
(profiles that downsample or fill holes have no bare equivalent: their ratio columns show '-').

Real raw EuRoC pairs (test/data/euroc) resized to each resolution, calibration scaled with them. The
stages: decode (two rclpy Images to arrays, as the node reads them), the StereoPipeline stages (rectify,
match, filter, depth), points (x, y, z and rgb computed straight into the organized 32-byte-point
PointCloud2, with the node's reused buffer, as the node does), encode (the DisparityImage). The bare
baseline does what a hand-written OpenCV script would: remap x2, the matcher, reprojectImageTo3D. Both run in the same
process, interleaved (profiles too, frame by frame), and the table gives medians and three ratios: the
pipeline alone / bare, everything the node does per frame (decode + pipeline + encode) / bare, and the
match stage / the first profile's match stage (`--profiles default quality`: quality's time in SGBM's).
A second table gives the cost of the glare invalidation (invalidate_saturated: both images' glare, the
right one's seen through the disparity) and of the spatial filter at 640x480 against the first profile's
match stage, interleaved with it (the EuRoC pair holds a bright window, so the glare stage does all its work).

    .venv/bin/python bench/pipeline_stages.py [--repeat 20] [--profiles default fast stereo_image_proc] [--markdown]
    .venv/bin/python bench/pipeline_stages.py --registration [--repeat 20] [--profiles default]

--registration: instead, at 640x480, the match stage against registering the frame's depth to a colour
camera (depth_registered/image_rect as stereo_node builds it: the colour image decoded, the depth projected
into it, the message), the right camera's raw image given again as the colour camera; interleaved frame by
frame in one run, medians and their ratio.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.core.matching import Matcher, MatchResult, create_matcher
from stereo_depth.core.params import StereoParams, make_params
from stereo_depth.core.pipeline import STAGES, StereoPipeline
from stereo_depth.core.saturation import invalidate_glare, rectified_glare
from stereo_depth.core.spatial import spatial_filter
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.kalibr import pose_of
from stereo_depth.frames import Geometry, disparity_message
from stereo_depth.frames.registered import FrameDepth, RegisteredJob, Registration
from stereo_depth.messages import (
    MessageBuffer,
    array_to_image,
    camera_info_to_msg,
    depth_to_cloud,
    image_to_pipeline,
    make_header,
)
from stereo_depth.options import OutputOptions
from stereo_depth.ros.types import RCLPY_TYPES

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row, times

EUROC = Path(__file__).resolve().parents[1] / "test" / "data" / "euroc"
RESOLUTIONS = ((640, 480), (1280, 720))
COLUMNS = ("decode", *STAGES, "encode")


def scaled_info(info: CameraInfo, width: int, height: int) -> CameraInfo:
    sx, sy = width / info.width, height / info.height
    scale = np.diag([sx, sy, 1.0])
    return dataclasses.replace(info, width=width, height=height, k=scale @ info.k, p=scale @ info.p)


def load_pair(width: int, height: int) -> tuple[np.ndarray, np.ndarray, StereoCamera]:
    name = sorted((EUROC / "left").glob("*.png"))[0].name
    left, right = (cv2.imread(str(EUROC / side / name), cv2.IMREAD_GRAYSCALE) for side in ("left", "right"))
    assert left is not None and right is not None, f"EuRoC pair {name} unreadable"
    left, right = cv2.resize(left, (width, height)), cv2.resize(right, (width, height))
    info_l, info_r = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    return left, right, StereoCamera(scaled_info(info_l, width, height), scaled_info(info_r, width, height))


def rectified_pair() -> tuple[np.ndarray, np.ndarray]:
    """The 640x480 EuRoC pair, rectified: what a matcher gets."""
    left, right, camera = load_pair(640, 480)
    return camera.rectify(left, "left"), camera.rectify(right, "right")


def bare_opencv(left: np.ndarray, right: np.ndarray, camera: StereoCamera, matcher: Matcher) -> float:
    """The same work written directly against OpenCV (maps prebuilt, as any careful script would)."""
    start = time.perf_counter()
    ml, mr = camera.rectification_maps("left"), camera.rectification_maps("right")
    rl = cv2.remap(left, ml[0], ml[1], cv2.INTER_LINEAR)
    rr = cv2.remap(right, mr[0], mr[1], cv2.INTER_LINEAR)
    disparity = matcher.compute(rl, rr).disparity
    cv2.reprojectImageTo3D(disparity, camera.q)
    return (time.perf_counter() - start) * 1000.0


def timed_frame(
    pipeline: StereoPipeline, messages: tuple[object, object], camera: StereoCamera, buffer: MessageBuffer
) -> dict[str, float]:
    """stereo_node's work for a disparity + points2 subscriber, as it does it (publish() not included):
    decode, match, depth, the cloud with the points computed straight into it (its 'points' stage),
    and the DisparityImage ('encode')."""
    header = make_header(RCLPY_TYPES, 1, "left")
    start = time.perf_counter()
    left, right = image_to_pipeline(messages[0]), image_to_pipeline(messages[1])
    decoded = time.perf_counter()
    result = pipeline.match(left, right, camera)
    pipeline.add_geometry(result, want_points=False)
    assert result.camera is not None and result.depth is not None
    geometry = time.perf_counter()
    rays = pipeline.rays_for(result.camera)
    depth_to_cloud(RCLPY_TYPES, header, result.depth, rays, result.left_rect, buffer=buffer)
    cloud = time.perf_counter()
    disparity_message(RCLPY_TYPES, header, result.disparity, result.camera, pipeline.params)
    end = time.perf_counter()
    ms = {**result.timings_ms, "decode": (decoded - start) * 1000.0, "points": (cloud - geometry) * 1000.0}
    ms["encode"] = (end - cloud) * 1000.0
    ms["pipeline"] = (cloud - decoded) * 1000.0
    ms["node"] = (end - start) * 1000.0
    return ms


def same_work(params: StereoParams) -> bool:
    """Whether a bare OpenCV script does this profile's work (no downsampling, no hole filling)."""
    return params.downsample == 1 and not params.fill_holes


def markdown_row(profile: str, size: str, med: dict[str, float], bare: list[float], first_match: float) -> str:
    """One table row: without a bare equivalent (no bare runs) the bare columns say so."""
    bare_cells = ("(no bare equivalent)", "")
    if bare:
        bare_ms = statistics.median(bare)
        bare_cells = (f"{bare_ms:.1f}", times(med["node"] / bare_ms))
    cells = (profile, size, f"{med['match']:.1f}", f"{med['pipeline']:.1f}", f"{med['node']:.1f}", *bare_cells)
    return table_row((*cells, times(med["match"] / first_match)))


def registration_job(
    pipeline: StereoPipeline, messages: tuple[object, object], camera: StereoCamera
) -> tuple[float, RegisteredJob]:
    """(match ms, a registered job of this frame's depth, the right camera as the colour camera)."""
    left, right = image_to_pipeline(messages[0]), image_to_pipeline(messages[1])
    result = pipeline.match(left, right, camera)
    pipeline.add_geometry(result, want_points=False)
    assert result.camera is not None and result.depth is not None
    # the right camera's raw frame in the left's: x_left_rect = R_l x_left, x_right_rect = R_r x_right - B e_x
    transform = np.eye(4)
    transform[:3, :3] = camera.left.r.T @ camera.right.r
    transform[:3, 3] = camera.left.r.T @ np.array([camera.baseline, 0.0, 0.0])
    pose = pose_of(transform)
    raw = camera.right
    colour = dataclasses.replace(raw, r=np.eye(3), p=np.hstack([raw.k, np.zeros((3, 1))]))
    header = make_header(RCLPY_TYPES, 1, "colour")
    geometry = Geometry(result.depth, result.camera, pipeline.rays_for(result.camera), result.left_rect, camera)
    registration = Registration(RCLPY_TYPES)
    registration.add_colour(messages[1], camera_info_to_msg(RCLPY_TYPES, header, colour))
    jobs = registration.add_depth(1, FrameDepth(geometry, OutputOptions(rgb_in_left=pose)))
    assert len(jobs) == 1
    return result.timings_ms["match"], jobs[0]


def registration_cost(args: argparse.Namespace) -> None:
    left, right, camera = load_pair(640, 480)
    header_msg = make_header(RCLPY_TYPES, 1, "left")
    messages = (array_to_image(RCLPY_TYPES, header_msg, left), array_to_image(RCLPY_TYPES, header_msg, right))
    pipelines = {p: StereoPipeline(make_params(p, {"disparity_range": args.disparity_range})) for p in args.profiles}
    match: dict[str, list[float]] = {p: [] for p in args.profiles}
    register: dict[str, list[float]] = {p: [] for p in args.profiles}
    for _ in range(args.repeat + 2):
        for profile in args.profiles:
            match_ms, job = registration_job(pipelines[profile], messages, camera)
            _, register_ms = job.run(("depth_registered/image_rect",))
            match[profile].append(match_ms)
            register[profile].append(register_ms)
    print("640x480, the right camera (raw, distorted) given again as the colour camera; medians:")
    print(table_header(("profile", "match ms", "registration ms", "registration / match")))
    for profile in args.profiles:
        match_ms, register_ms = (statistics.median(runs[profile][2:]) for runs in (match, register))
        print(table_row((profile, f"{match_ms:.1f}", f"{register_ms:.1f}", times(register_ms / match_ms))), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--profiles", nargs="+", default=["default", "fast", "stereo_image_proc"])
    parser.add_argument("--disparity-range", type=int, default=64)
    parser.add_argument("--registration", action="store_true", help="the cost of registered depth against matching")
    args = parse_bench_arguments(parser)
    if args.registration:
        registration_cost(args)
        return
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, disparity_range {args.disparity_range}")
    if args.markdown:
        columns = ("profile", "size", "match ms", "pipeline ms", "node ms", "bare OpenCV ms", "node / bare")
        print(table_header((*columns, f"match / {args.profiles[0]}")))
    else:
        header = f"{'profile':18s}{'size':>10s}" + "".join(f"{s:>8s}" for s in COLUMNS)
        print(
            header
            + f"{'pipeline':>9s}{'node':>8s}{'bare cv':>8s}{'pipe/bare':>10s}{'node/bare':>10s}"
            + f"  match/{args.profiles[0]}"
        )
    for width, height in RESOLUTIONS:
        left, right, camera = load_pair(width, height)
        header_msg = make_header(RCLPY_TYPES, 1, "left")
        messages = (array_to_image(RCLPY_TYPES, header_msg, left), array_to_image(RCLPY_TYPES, header_msg, right))
        params = {p: make_params(p, {"disparity_range": args.disparity_range}) for p in args.profiles}
        pipelines = {p: StereoPipeline(params[p]) for p in args.profiles}
        buffers = {p: MessageBuffer() for p in args.profiles}
        bare_matchers = {p: create_matcher(params[p]) for p in args.profiles}
        runs: dict[str, list[dict[str, float]]] = {p: [] for p in args.profiles}
        bare: dict[str, list[float]] = {p: [] for p in args.profiles}
        for _ in range(args.repeat + 2):  # profiles interleaved: a load change on the machine hits them all alike
            for profile in args.profiles:
                runs[profile].append(timed_frame(pipelines[profile], messages, camera, buffers[profile]))
                if same_work(params[profile]):
                    bare[profile].append(bare_opencv(left, right, camera, bare_matchers[profile]))
        first = statistics.median(r["match"] for r in runs[args.profiles[0]][2:])
        for profile in args.profiles:
            med = {k: statistics.median(r[k] for r in runs[profile][2:]) for k in runs[profile][0]}
            if args.markdown:
                print(markdown_row(profile, f"{width}x{height}", med, bare[profile][2:], first), flush=True)
                continue
            row = f"{profile:18s}{f'{width}x{height}':>10s}" + "".join(f"{med[c]:8.1f}" for c in COLUMNS)
            row += f"{med['pipeline']:9.1f}{med['node']:8.1f}"
            if same_work(params[profile]):
                bare_ms = statistics.median(bare[profile][2:])
                row += f"{bare_ms:8.1f}{med['pipeline'] / bare_ms:10.2f}{med['node'] / bare_ms:10.2f}"
            else:  # downsampling / hole filling: no bare OpenCV call does the same work
                row += f"{'-':>8s}{'-':>10s}{'-':>10s}"
            print(row + f"{med['match'] / first:10.2f}", flush=True)
    option_costs(args.profiles[0], args.disparity_range, args.repeat)


def option_costs(profile: str, disparity_range: int, repeat: int) -> None:
    """The glare invalidation's and the spatial filter's time per 640x480 frame against the match stage."""
    left, right, camera = load_pair(640, 480)
    params = make_params(profile, {"disparity_range": disparity_range, "invalidate_saturated": False})
    pipeline = StereoPipeline(params)
    runs: dict[str, list[float]] = {"match": [], "invalidate_saturated": [], "spatial_filter": []}
    for _ in range(repeat + 2):
        result = pipeline.match(left, right, camera)
        runs["match"].append(result.timings_ms["match"])
        start = time.perf_counter()
        shape = result.left_rect.shape
        glare = rectified_glare(left, result.left_rect, camera, "left", shape, params.saturation_level)
        right_glare = rectified_glare(right, result.right_rect, camera, "right", shape, params.saturation_level)
        invalidate_glare(MatchResult(result.disparity.copy()), glare, right_glare)
        glared = time.perf_counter()
        spatial_filter(result.disparity, params.spatial, result.left_rect)
        runs["invalidate_saturated"].append((glared - start) * 1000.0)
        runs["spatial_filter"].append((time.perf_counter() - glared) * 1000.0)
    med = {name: statistics.median(times_ms[2:]) for name, times_ms in runs.items()}
    glare_share = float(glare.mean()) if glare is not None else 0.0
    print(f"\nprocessing options at 640x480, `{profile}` (glare: {glare_share:.3f} of the left image):")
    print(table_header(("stage", "ms per frame", "vs match")))
    for name, ms in med.items():
        print(table_row((name, f"{ms:.2f}", times(ms / med["match"]))))


if __name__ == "__main__":
    main()
