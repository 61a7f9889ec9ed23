"""A recorded stereo bag through the live node's pipeline, into a bag of results.

The same FrameStream (stereo_depth.frames) and synchronizer as `stereo_node`, so a bag processed here
and the same bag replayed into the node give bit-identical outputs. With `left_in_base` set, the odometry
goes to the stream as a live node has it when it takes a frame: every message stamped up to the frame's
stamp plus `odom_wait_seconds` (`OdometryFeed`).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.bag.export import disparity_picture, write_ply
from stereo_depth.bag.reader import ReadStats, StereoBagReader, TimeWindow, TopicChoice
from stereo_depth.bag.types import rosbags_types
from stereo_depth.bag.writer import BagWriter, check_output
from stereo_depth.core.geometry import depth_to_points
from stereo_depth.core.odometry import OdometrySample, OdometryTrack
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import STAGES, StereoResult
from stereo_depth.core.temporal import lead_in_frames
from stereo_depth.errors import BagError, StereoDepthError
from stereo_depth.frames import DEFAULT_OUTPUTS, FrameOutputs, FrameStream, Geometry
from stereo_depth.frames.odometry import odometry_note
from stereo_depth.frames.registered import REGISTERED_OUTPUTS, ColourNames, RegisteredJob, check_registered_outputs
from stereo_depth.messages import ODOMETRY_TYPE
from stereo_depth.options import NodeOptions, OutputOptions
from stereo_depth.sync import StereoSet


@dataclass
class ProcessOptions:
    namespace: str | None = None
    topics: TopicChoice | None = None  # --left/--right/--camera-info (its namespace wins over the one above)
    sync: NodeOptions = field(default_factory=NodeOptions)  # its sync options, as the node's
    storage: str = "mcap"
    compress: bool = False  # zstd chunks (MCAP only); off by default, as in `ros2 bag record`
    outputs: tuple[str, ...] = DEFAULT_OUTPUTS  # stereo_node's default outputs (colour, confidence: when there)
    output: OutputOptions = field(default_factory=OutputOptions)  # how outputs are built, as the nodes'
    overwrite: bool = False
    png_dir: Path | None = None
    ply_dir: Path | None = None  # one PLY per frame
    ply_frames: int | None = None  # write PLYs for the first N frames only (None: all)
    window: TimeWindow | None = None  # one shard of a long bag (stereo_depth.fleet); None: the whole bag
    custom_data: dict[str, str] = field(default_factory=dict)  # recorded in the output's metadata.yaml
    progress: bool = True  # the per-bag progress line (fleet runs draw one line for all bags instead)


@dataclass
class ProcessSummary:
    left_images: int = 0
    right_images: int = 0
    frames_out: int = 0
    unmatched: int = 0
    skipped: Counter[str] = field(default_factory=Counter)
    seconds: float = 0.0
    stage_ms: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    topics: list[str] = field(default_factory=list)
    read: ReadStats = field(default_factory=ReadStats)
    pictures: list[Path] = field(default_factory=list)
    clouds: list[Path] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # each once: what held for frames that still came out
    notes: list[str] = field(default_factory=list)  # each once: worth knowing, nothing lost
    odometry_events: Counter[str] = field(default_factory=Counter)  # odometry note -> frames it was seen at
    registered: int = 0  # colour images registered (rgb_in_left)
    without_colour: int = 0  # stereo frames no colour image paired with

    @property
    def frames_per_second(self) -> float:
        return self.frames_out / self.seconds if self.seconds > 0 else 0.0

    def mean_stage_ms(self) -> dict[str, float]:
        return {k: v / max(1, self.frames_out) for k, v in self.stage_ms.items()}

    def why_empty(self) -> str:
        """Why no frame came out, on one line: the commonest reason a frame was skipped, or the pairing."""
        seen = f"{self.left_images} left / {self.right_images} right images"
        if self.skipped:
            reason, count = self.skipped.most_common(1)[0]
            others = sum(self.skipped.values()) - count
            more = f" (and {others} frames for other reasons)" if others else ""
            return f"no frame was processed from {seen}: {count} skipped because {reason}{more}"
        if self.unmatched:
            return (
                f"no frame was processed from {seen}: no set of messages had equal stamps "
                f"({self.unmatched} unmatched); try --approximate-sync or a larger --queue-size"
            )
        return f"no frame was processed: the bag has {seen}"

    def lines(self) -> list[str]:
        out = [
            f"frames in: {self.left_images} left / {self.right_images} right images; "
            f"frames out: {self.frames_out}; unmatched: {self.unmatched}; skipped: {sum(self.skipped.values())}; "
            f"{self.frames_per_second:.1f} frames/s"
        ]
        if self.unmatched:
            out.append(
                f"  unmatched: {self.unmatched} messages found no partner with the same stamp "
                "(try --approximate-sync, or a larger --queue-size)"
            )
        if self.registered or self.without_colour:
            out.append(
                f"  registered: {self.registered} colour images; {self.without_colour} frames had no colour image "
                "within rgb_sync_tolerance_seconds"
            )
        out.extend(f"  skipped {n}x: {reason}" for reason, n in self.skipped.most_common())
        out.extend(f"  warning: {text}" for text in self.warnings)
        out.extend(f"  {text} ({n}x)" for text, n in self.odometry_events.items())
        out.extend(f"  note: {text}" for text in self.notes)
        timings = ", ".join(f"{k} {v:.1f}" for k, v in self.mean_stage_ms().items())
        out.append(f"mean per-stage time, ms: {timings}")
        return out


class Progress:
    """One `\r` line on stderr with frames/s, only when stderr is a terminal."""

    def __init__(self, total: int, enabled: bool = True) -> None:
        self.total = max(total, 1)
        self.enabled = enabled and sys.stderr.isatty()
        self.start = time.perf_counter()

    def update(self, done: int) -> None:
        if not self.enabled:
            return
        rate = done / max(time.perf_counter() - self.start, 1e-9)
        filled = int(30 * min(done, self.total) / self.total)
        sys.stderr.write(f"\r[{'#' * filled}{'.' * (30 - filled)}] {done}/{self.total} frames  {rate:5.1f} frames/s")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def _export(
    index: int,
    stamp_ns: int,
    result: StereoResult,
    disparity: np.ndarray,
    geometry: Geometry | None,
    params: StereoParams,
    options: ProcessOptions,
    summary: ProcessSummary,
) -> None:
    stem = f"{index:04d}_{stamp_ns}"
    left = result.left_rect_color if result.left_rect_color is not None else result.left_rect
    if options.png_dir is not None:
        path = options.png_dir / f"{stem}.png"
        cv2.imwrite(str(path), disparity_picture(left, disparity, params.min_disparity + params.disparity_range))
        summary.pictures.append(path)
    wants_ply = options.ply_frames is None or index < options.ply_frames
    if options.ply_dir is not None and wants_ply and geometry is not None:
        path = options.ply_dir / f"{stem}.ply"
        write_ply(path, depth_to_points(geometry.depth, geometry.rays), geometry.image)
        summary.clouds.append(path)


class OdometryFeed:
    """A bag's odometry (in stamp order) handed to a stream's track as a live node has it when it takes a
    frame: the node waits up to `wait_s` for the message at or after the frame's stamp, so every message
    stamped up to the frame's stamp plus `wait_s` is there, and none later."""

    def __init__(self, samples: list[OdometrySample], track: OdometryTrack, wait_s: float) -> None:
        self._samples, self._track, self._wait_ns = samples, track, round(wait_s * 1e9)
        self._next = 0

    def until(self, stamp_ns: int) -> None:
        """Before the frame at `stamp_ns` (frames come in stamp order)."""
        samples = self._samples
        while self._next < len(samples) and samples[self._next].stamp_ns <= stamp_ns + self._wait_ns:
            self._track.add(samples[self._next])
            self._next += 1


def unused_odometry_note(topics: dict[str, str], odom: str, output: OutputOptions) -> str | None:
    """The note for a bag whose odometry is left unused (left_in_base unset), if it has one."""
    if output.left_in_base.is_set or topics.get(odom) != ODOMETRY_TYPE:
        return None
    return (
        f"the bag has odometry ({odom}); set left_in_base (the left camera in the odometry's child frame) for "
        "the temporal filter to move its history with the camera"
    )


FrameCallback = Callable[[int, StereoSet, FrameOutputs], None]


def process_bag(
    in_bag: Path,
    out_bag: Path,
    params: StereoParams,
    options: ProcessOptions | None = None,
    on_frame: FrameCallback | None = None,
) -> ProcessSummary:
    """Process every matched frame of `in_bag` into `out_bag`; nothing appears at `out_bag` on failure."""
    options = options or ProcessOptions()
    check_registered_outputs(options.outputs, options.output)
    registered_outputs = tuple(name for name in options.outputs if name in REGISTERED_OUTPUTS)
    choice = dataclasses.replace(
        options.topics or TopicChoice(namespace=options.namespace),
        with_rgb=bool(registered_outputs),
        with_odom=options.output.left_in_base.is_set and params.temporal_filter,  # only the filter reads it
    )
    check_output(out_bag, options.overwrite)
    for folder in (options.png_dir, options.ply_dir):
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)
    summary = ProcessSummary()
    start = time.perf_counter()
    with (
        StereoBagReader(
            in_bag,
            namespace=options.namespace,
            sync=options.sync,
            choice=choice,
            window=options.window,
            lead_in_frames=lead_in_frames() if params.temporal_filter else 0,
        ) as reader,
        BagWriter(
            out_bag,
            storage=options.storage,
            overwrite=options.overwrite,
            compress=options.compress,
            custom_data=options.custom_data,
        ) as writer,
    ):
        topics = reader.topics
        # its cloud buffer: the writer serializes each message before the next frame
        stream = FrameStream(
            rosbags_types(),
            params,
            options.output,
            rectified=topics.rectified,
            names=topics.input_names,
            colour_names=ColourNames(*(name or "rgb --camera-info" for name in topics.rgb or ColourNames())),
        )

        def write_registered(jobs: Iterable[RegisteredJob]) -> None:
            for job in jobs:
                try:
                    messages, _ = job.run(registered_outputs)
                except StereoDepthError as exc:
                    summary.skipped[str(exc)] += 1
                    continue
                summary.registered += 1
                for name, message in messages.items():
                    write(name, message, job.stamp_ns)

        def write(name: str, message: object, stamp_ns: int) -> None:
            writer.write(topics.output(name), message, stamp_ns)
            if topics.output(name) not in summary.topics:
                summary.topics.append(topics.output(name))

        odometry = OdometryFeed(reader.odometry(), stream.odometry, options.output.odom_wait_seconds)
        note = unused_odometry_note(reader.topic_types(), topics.output("odom"), options.output)
        if note is not None:
            summary.notes.append(note)
        progress = Progress(reader.count(topics.names[0]), options.progress)
        for inputs in reader.frames():
            while reader.colour_sets:  # the colour images recorded before this frame was complete
                stream.registration.add_colour(*reader.colour_sets.popleft())
            odometry.until(inputs.stamp_ns)
            if inputs.lead_in:  # a shard's frames before its first: only to fill the temporal filter
                stream.lead_in(inputs)
                continue
            try:
                out = stream.match(inputs, options.outputs, with_geometry=options.ply_dir is not None)
                cloud = out.cloud.run() if out.cloud is not None else None  # written only once the frame is whole
            except StereoDepthError as exc:
                summary.skipped[str(exc)] += 1
                continue
            reason = out.frame.camera.no_depth_reason
            if reason is not None and reason not in summary.warnings:
                summary.warnings.append(reason)
            if out.odometry_event is not None:
                summary.odometry_events[odometry_note(out.odometry_event, str(topics.odom))] += 1
            messages = {**out.images, **(cloud.messages if cloud is not None else {})}
            for name, message in messages.items():
                write(name, message, inputs.stamp_ns)
            write_registered(cloud.registered if cloud is not None else ())
            stage_ms = {**out.stage_ms, **(cloud.stage_ms if cloud is not None else {})}
            for stage, ms in stage_ms.items():
                summary.stage_ms[stage] = summary.stage_ms.get(stage, 0.0) + ms  # "temporal" only when on
            geometry = cloud.geometry if cloud is not None else None
            _export(summary.frames_out, inputs.stamp_ns, out.result, out.disparity, geometry, params, options, summary)
            if on_frame is not None:
                on_frame(summary.frames_out, inputs, out)
            summary.frames_out += 1
            progress.update(summary.frames_out)
        while reader.colour_sets:
            stream.registration.add_colour(*reader.colour_sets.popleft())
        write_registered(stream.registration.flush())
        if registered_outputs:
            summary.without_colour = stream.registration.counters.unpaired_primary
        progress.close()
        stats = summary.read = reader.stats
        summary.left_images, summary.right_images = stats.left_images, stats.right_images
        summary.unmatched = (stats.sync.dropped if stats.sync else 0) + stats.unmatched_at_end
        if summary.frames_out == 0 and options.window is None:  # a shard may own no frame; a bag must
            raise BagError(summary.why_empty())  # inside the writer's block: no empty bag is left behind
    summary.seconds = time.perf_counter() - start
    return summary
