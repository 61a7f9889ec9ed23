"""What one worker runs: a bag, or one time window of a bag, through `process_bag`.

A task never raises for a bad bag: the error comes back as text in its result, so one damaged bag
cannot stop the others. Only an interruption (Ctrl-C, a killed worker) propagates, after
`process_bag` has removed its half-written output. A task given a `stop_file` also stops, between
frames, once that file exists (how a Ray run is interrupted): its output is removed the same way.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereo_depth.bag.process import ProcessOptions, process_bag
from stereo_depth.bag.reader import TimeWindow
from stereo_depth.core.matching import ONE_CORE_SGBM_MODES, create_matcher, min_image_size
from stereo_depth.core.params import StereoParams
from stereo_depth.core.threads import thread_counts, use_threads
from stereo_depth.errors import StereoDepthError

RECORD_KEY = "stereo_depth.process"  # metadata.yaml custom_data key holding what made the output


@dataclass(frozen=True)
class Task:
    bag: str  # the output name: which bag this task belongs to
    source: Path
    output: Path  # the bag's output, or its shard's part bag
    params: StereoParams
    options: ProcessOptions
    shard: int = 0
    window: TimeWindow | None = None
    threads: int = 0  # OpenCV / numba threads: the cores this task was given; 0 = as the process has them
    stop_file: Path | None = None  # once it exists, the task stops between frames and leaves no output


@dataclass
class TaskResult:
    bag: str
    shard: int = 0
    frames_in: int = 0
    frames_out: int = 0
    seconds: float = 0.0
    error: str | None = None
    first_ns: int | None = None
    handoff_ns: int | None = None
    threads: dict[str, int] = field(default_factory=dict)  # what OpenCV and numba matched with


def matcher_cores(params: StereoParams) -> int:
    """Cores one frame keeps busy: OpenCV SGBM in its one-core modes is matched as two halves at once
    (matching.Halves); every other matcher here runs one frame on one core."""
    return 2 if params.matcher == "sgbm" and params.sgbm_mode in ONE_CORE_SGBM_MODES else 1


# ProcessOptions fields that change where and how a run goes, not the output bag's messages. Every other
# field, including any added later, is part of an output's record: a rerun redoes rather than wrongly skips.
NOT_IN_RECORD = frozenset({"overwrite", "png_dir", "ply_dir", "ply_frames", "window", "custom_data", "progress"})


def record(params: StereoParams, options: ProcessOptions) -> str:
    """Everything that changes an output's messages, as the JSON stored in it: an output made with
    the same record is complete and current, so a rerun skips its input."""
    made_with = {k: v for k, v in dataclasses.asdict(options).items() if k not in NOT_IN_RECORD}
    return json.dumps({"params": dataclasses.asdict(params), **made_with}, sort_keys=True, default=_json_value)


def _json_value(value: object) -> object:
    """Arrays (a calibration file's K, D, R, P) as lists; anything else JSON lacks as its text."""
    return value.tolist() if isinstance(value, np.ndarray) else str(value)


@functools.cache
def warm_up(params: StereoParams) -> None:
    """Compile (or load from numba's cache) the census core once per worker process, not per bag."""
    if params.matcher != "census_sgm":
        return
    width, height = min_image_size(params)
    image = np.zeros((max(height, 16), width + 16), np.uint8)
    create_matcher(params).compute(image, image)


STOPPED = "stopped: the run was interrupted"


class StopRequestedError(Exception):
    """The task's stop file appeared: unwinds process_bag, whose writer deletes the partial output."""


def _stop_if_asked(stop_file: Path, *_: object) -> None:
    if stop_file.exists():
        raise StopRequestedError


def run_task(task: Task) -> TaskResult:
    if task.stop_file is not None and task.stop_file.exists():  # queued behind others when the run stopped
        return TaskResult(task.bag, task.shard, error=STOPPED)
    warm_up(task.params)
    if task.threads:
        use_threads(task.threads)  # after warm_up, which loads numba for census_sgm
    result = TaskResult(task.bag, task.shard)
    start = time.perf_counter()
    options = dataclasses.replace(task.options, window=task.window, progress=False)
    stop = functools.partial(_stop_if_asked, task.stop_file) if task.stop_file is not None else None
    try:
        summary = process_bag(task.source, task.output, task.params, options, on_frame=stop)
    except StopRequestedError:
        result.error = STOPPED
    except Exception as exc:  # any failure of one bag is that bag's result, not the run's
        result.error = str(exc) if isinstance(exc, StereoDepthError) else f"{type(exc).__name__}: {exc}"
    else:
        result.frames_in, result.frames_out = summary.left_images, summary.frames_out
        result.first_ns, result.handoff_ns = summary.read.first_ns, summary.read.handoff_ns
    result.seconds = time.perf_counter() - start
    result.threads = thread_counts()
    return result
