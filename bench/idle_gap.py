"""Does a match run slower after the cores sat idle, or after the previous frame's cloud? A node at 30 Hz
idles between frames.

stereo_node's first stage (stereo_image_proc's parameters: BM on both halves at once) on the anchor's
VGA frames, in interleaved rounds (each starting one mode later than the one before), with before each
frame:
  * nothing (frame after frame);
  * an idle gap (sleep);
  * the same gap, with the lower half's helper thread placed wherever the scheduler wakes it (as before
    core/threads.py `OtherCore` kept it off its caller's core);
  * the same gap spent spinning, so the machine never idles;
  * the same gap after the previous frame's cloud stage, started on a second thread as the node starts
    it: depth, then points2 with 32-byte (the default) or 16-byte points written into its reused buffer
    and serialized as rclpy's publish() serializes it (the cloud stage ends within the gap).
Prints the median ms per frame of each and its ratio to frame after frame, and the share of frames whose
lower half started on the core its caller ran on as it handed the half over. On a VM whose guest kernel
takes a halted vCPU for a busy one, a thread woken after an idle gap lands on its waker's core: the halves
then share one core and take as long as the whole image on one thread; the helper's placement row shows
what that costs. If the cloud's ~10 MB of copies evicted what the next match needs, its rows would be
slower than the idle gap's.

    .venv/bin/python bench/idle_gap.py [--gap-ms 20] [--frames 60] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any
from unittest import mock

from stereo_depth.core import threads
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.frames import OutputState, StereoFrame, geometry_outputs, match_frame, result_geometry
from stereo_depth.messages import make_header
from stereo_depth.options import OutputOptions
from stereo_depth.ros.types import RCLPY_SERIALIZED, RCLPY_TYPES

sys.path.insert(0, str(Path(__file__).parent))
from anchor_frames import FRAME_ID, camera_infos, frames
from markdown_table import parse_bench_arguments, table_header, table_row, times

CLOUD_MODES = {"idle gap after a 32-byte cloud": False, "idle gap after a 16-byte cloud": True}  # avoid_padding
UNPLACED = "idle gap, helper where the scheduler wakes it"
MODES = ("frame after frame", "idle gap", UNPLACED, "gap spent spinning", *CLOUD_MODES)


def spin(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


class CloudStage:
    """The node's second stage for one frame, on a thread of its own: its own `result_geometry` and
    `geometry_outputs` (stereo_depth/frames/) build points2 in its serialized bytes."""

    def __init__(self, pipeline: StereoPipeline) -> None:
        self._pipeline = pipeline
        self._thread = ThreadPoolExecutor(max_workers=1)
        self._states = {avoid_padding: OutputState() for avoid_padding in CLOUD_MODES.values()}  # reused buffers

    def start(self, frame: StereoFrame, result: StereoResult, avoid_padding: bool) -> Future[None]:
        return self._thread.submit(self._run, frame, result, avoid_padding)

    def _run(self, frame: StereoFrame, result: StereoResult, avoid_padding: bool) -> None:
        geometry = result_geometry(self._pipeline, frame, result)
        options = OutputOptions(avoid_point_cloud_padding=avoid_padding)
        state = self._states[avoid_padding]
        points2 = geometry_outputs(RCLPY_SERIALIZED, frame.header, geometry, options, ("points2",), state)["points2"]
        points2.buffer.tobytes()  # built in its serialized bytes; publishing copies them once into DDS


class HelperPlacement:
    """Lets the lower half's helper be kept off its caller's core (the node's way) or placed by the scheduler
    alone (`placed = False`), and records whether the helper started on the core its caller was on."""

    def __init__(self) -> None:
        self.placed = True
        self.shared_a_core = False
        keep_off, submit = threads.keep_off_current_core, threads.OtherCore.submit

        def recorded(helper: threads.OtherCore, job: Callable[[], Any]) -> Future[Any]:
            caller = threads.current_core()

            def started() -> Any:
                self.shared_a_core = threads.current_core() == caller
                return job()

            return submit(helper, started)

        mock.patch.object(threads, "keep_off_current_core", lambda tid: self.placed and keep_off(tid)).start()
        mock.patch.object(threads.OtherCore, "submit", recorded).start()


def spend_gap(mode: str, seconds: float, clouds: CloudStage, previous: tuple[StereoFrame, StereoResult] | None) -> None:
    """The `seconds` before a frame as `mode` spends them; `previous`: the last frame and its match, if any."""
    if mode == "frame after frame":
        return
    if mode == "gap spent spinning":
        spin(seconds)
        return
    stage: Future[None] | None = None
    if mode in CLOUD_MODES and previous is not None:
        stage = clouds.start(*previous, CLOUD_MODES[mode])
    time.sleep(seconds)
    if stage is not None:
        stage.result()  # ends within the gap: the next match has the cores to itself


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gap-ms", type=float, default=20.0, help="idle time before each frame")
    parser.add_argument("--frames", type=int, default=60, help="frames per round and mode")
    parser.add_argument("--rounds", type=int, default=3)
    args = parse_bench_arguments(parser)
    gap_s = args.gap_ms / 1000.0
    pipeline = StereoPipeline(make_params("stereo_image_proc"))
    helper = HelperPlacement()
    camera = pipeline.camera_for(*camera_infos(640, 480))
    header = make_header(RCLPY_TYPES, 0, FRAME_ID)
    clouds = CloudStage(pipeline)
    pairs = list(frames(640, 480, 20))
    ms: dict[str, list[float]] = {mode: [] for mode in MODES}
    shared: dict[str, list[bool]] = {mode: [] for mode in MODES}
    for round_ in range(args.rounds):
        for mode in MODES[round_ % len(MODES) :] + MODES[: round_ % len(MODES)]:  # each round starts one later
            previous = None
            helper.placed = mode != UNPLACED
            for i in range(args.frames):
                spend_gap(mode, gap_s, clouds, previous)
                left, right = pairs[i % len(pairs)]
                frame = StereoFrame(i, header, left, right, camera, rectified=False)
                start = time.perf_counter()
                previous = frame, match_frame(pipeline, frame)
                ms[mode].append((time.perf_counter() - start) * 1000.0)
                shared[mode].append(helper.shared_a_core)
    baseline = statistics.median(ms[MODES[0]])
    print(f"BM 640x480, 64 disparities, window 15; gap {args.gap_ms:g} ms; {args.rounds} rounds x {args.frames} frames")
    if args.markdown:
        print(
            table_header(("before each frame", "ms per frame (median)", "vs frame after frame", "halves on one core"))
        )
    for mode in MODES:
        median = statistics.median(ms[mode])
        one_core = f"{100.0 * statistics.fmean(shared[mode]):.0f}%"
        cells = (mode, f"{median:.2f}", times(median / baseline), one_core)
        print(table_row(cells) if args.markdown else f"{cells[0]:46s} {cells[1]:>6s} ms  {cells[2]}  {cells[3]:>4s}")


if __name__ == "__main__":
    main()
