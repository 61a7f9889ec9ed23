"""What a node reports on `diagnostics` about once a second, and the counters behind it.

Rates and losses are what users need to see first when depth looks wrong: an input that arrives
slower than its camera sends (QoS mismatch, DDS fragments lost, a CPU that cannot keep up) shows as
`<topic> missing` here before it shows as holes in the point cloud.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field
from statistics import median

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from stereo_depth.core.calibration_check import CalibrationCheck
from stereo_depth.core.pipeline import STAGES
from stereo_depth.sync import SyncCounters

WINDOW = 50  # messages per input used to estimate rates
SILENT_AFTER_S = 3.0  # an input quiet this long while the others arrive is reported by name
RECENT_FRAMES = 30  # frames averaged for stage times and latency
LOSS_HELP = "see docs/dds.md#large-messages"  # why DDS loses large inputs, and the fix
BOTTLENECK_HELP = "see docs/dds.md#where-frames-go"
TOO_NEAR_WARN_SHARE = 0.05  # recent frames' mean share of too-near pixels that a warning names


@dataclass
class RateMonitor:
    """Arrival rate of one input versus the rate its publisher sends, judged from header stamps.

    The sender's period is the smallest typical stamp step (10th percentile): with half the frames
    lost some consecutive pairs still arrive, so the period is not mistaken for twice its value.
    """

    stamps: deque[tuple[int, float]] = field(default_factory=lambda: deque(maxlen=WINDOW))
    lost_reported: int = 0  # DDS "message lost" events
    unmatched: int = 0  # received, but never part of a set (no partner, queue overflow, stale stamp)
    substituted: int = 0  # camera_info: sets that took the last one because theirs was missing
    late: int = 0  # camera_info: arrived after its set went out (a DDS repair)

    def add(self, stamp_ns: int, arrival_s: float) -> None:
        if self.stamps and stamp_ns <= self.stamps[-1][0]:
            self.stamps.clear()  # a time jump (bag loop, restarted driver) starts a new estimate
        self.stamps.append((stamp_ns, arrival_s))

    def received_hz(self, now_s: float) -> float:
        recent = [t for _, t in self.stamps if now_s - t <= 2.0]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def sender_hz(self) -> float:
        steps = sorted(b[0] - a[0] for a, b in zip(self.stamps, list(self.stamps)[1:], strict=False))
        if not steps:
            return 0.0
        period = steps[len(steps) // 10]
        return 1e9 / period if period > 0 else 0.0

    def missing(self) -> int:
        """Frames the stamps say were sent within the window but never arrived."""
        hz = self.sender_hz()
        if hz <= 0:
            return 0
        span_s = (self.stamps[-1][0] - self.stamps[0][0]) / 1e9
        return max(0, round(span_s * hz) + 1 - len(self.stamps))


class NodeDiagnostics:
    """Thread-safe counters (callbacks and the worker both write) and their DiagnosticArray."""

    def __init__(self, node_name: str, inputs: list[str]) -> None:
        self._name = node_name
        self._lock = threading.Lock()
        self.inputs = {topic: RateMonitor() for topic in inputs}
        self._outputs: deque[float] = deque(maxlen=WINDOW)
        self._stage_ms: dict[str, deque[float]] = {}  # the last RECENT_FRAMES frames
        self._latency_s: deque[float] = deque(maxlen=RECENT_FRAMES)
        self._age_s: dict[str, deque[float]] = {}  # per output: its age at publish, from the input's receipt
        self._in_dds_ms: dict[str, deque[float]] = {}  # per input: its DDS receipt minus its writer's send time
        self.dropped = 0  # complete sets replaced by a newer one before the worker got to them
        self.dropped_late = 0  # of those, sets that could not be out within max_latency_ms
        self.dropped_clouds = 0  # disparities published whose depth / points2 a newer frame replaced
        self.unmatched = 0  # messages the synchronizer discarded (no partner, queue overflow, stale)
        self.calibration_unknown = 0  # sets dropped: no camera_info yet, or it changed where one was lost
        self._reported: dict[str, int] = {}  # counters at the previous report: what grew since names the bottleneck
        self.processed = 0
        self.last_error = ""
        self._last_error_at = 0.0
        self._calibration: tuple[int, CalibrationCheck] | None = None  # (stamp checked, result)
        self._last_arrival: dict[str, float] = {}
        self.stale = 0  # messages whose stamp repeated or went back a little (dropped)
        self.time_jumps = 0  # stamps went back by more than the synchronizer's jump: pairing restarted
        self.calibrations = 0  # calibrations loaded (rectification maps built); grows only on a change
        self.without_colour: int | None = None  # frames no colour image paired with (None: not registering)
        self._too_near: deque[float] = deque(maxlen=RECENT_FRAMES)  # share of each frame's pixels
        self._nearest_depth = float("nan")  # metres: the nearest depth the disparity range can see

    def input_received(self, topic: str, stamp_ns: int) -> None:
        now = time.monotonic()
        with self._lock:
            self.inputs[topic].add(stamp_ns, now)
            self._last_arrival[topic] = now

    def input_in_dds(self, topic: str, ms: float) -> None:
        """How long a message took from its publisher's write to this node's DDS reader (both clocks of
        the message's DDS sample info: between machines their offset is in it)."""
        with self._lock:
            self._in_dds_ms.setdefault(topic, deque(maxlen=RECENT_FRAMES)).append(ms)

    def sync_changed(self, change: SyncCounters, topics: list[str] | None = None) -> None:
        """What one message did to a synchronizer (`SyncCounters.since`), per input topic: `topics`, its
        inputs (None: the node's first inputs, the stereo set's)."""
        with self._lock:
            self.stale += change.stale
            self.time_jumps += change.time_jumps
            self.unmatched += change.dropped + change.stale
            self.calibration_unknown += change.calibration_unknown
            monitors = [self.inputs[t] for t in topics] if topics is not None else list(self.inputs.values())
            for monitor, dropped, substituted, late in zip(
                monitors[: len(change.dropped_by_input)],
                change.dropped_by_input,
                change.substituted,
                change.late,
                strict=True,
            ):
                monitor.unmatched += dropped
                monitor.substituted += substituted
                monitor.late += late

    def registration(self, without_colour: int) -> None:
        """Registered outputs: the stereo frames that no colour image paired with, so far."""
        with self._lock:
            self.without_colour = without_colour

    def calibrations_loaded(self, count: int) -> None:
        with self._lock:
            self.calibrations = count

    def silent_inputs(self) -> str:
        """'' while all inputs arrive, else which ones are quiet while others arrive, and the fix."""
        with self._lock:
            return self._silence(time.monotonic())

    def _silence(self, now: float) -> str:
        """One camera down, camera_info never published or a topic remapped wrong all look like this."""
        arriving = sorted(t for t, at in self._last_arrival.items() if now - at < SILENT_AFTER_S)
        if not arriving:
            return ""  # nothing is published at all: nothing to pair, nothing to complain about
        quiet = [
            f"{t} (for {now - self._last_arrival[t]:.0f} s)" if t in self._last_arrival else f"{t} (never)"
            for t in self.inputs
            if t not in arriving
        ]
        if not quiet:
            return ""
        return (
            f"no messages on {', '.join(quiet)} while {', '.join(arriving)} arrive; check its publisher (the "
            "camera's driver, or the odometry) and the topic remapping (ros2 topic hz)"
        )

    def input_lost(self, topic: str, count: int) -> None:
        with self._lock:
            self.inputs[topic].lost_reported += count

    def frame_done(self, stage_ms: dict[str, float], latency_s: float) -> None:
        with self._lock:
            self.processed += 1
            self._outputs.append(time.monotonic())
            for stage, ms in stage_ms.items():
                self._stage_ms.setdefault(stage, deque(maxlen=RECENT_FRAMES)).append(ms)
            self._latency_s.append(latency_s)

    def too_near(self, share: float, nearest_depth: float) -> str:
        """One frame's share of pixels too near for the disparity range; returns a warning to log (throttled
        by the caller) while the recent frames' mean share stays above TOO_NEAR_WARN_SHARE, else ''."""
        with self._lock:
            self._too_near.append(share)
            self._nearest_depth = nearest_depth
            recent = sum(self._too_near) / len(self._too_near)
        if len(self._too_near) < RECENT_FRAMES or recent <= TOO_NEAR_WARN_SHARE:
            return ""
        return (
            f"{100 * recent:.0f} % of the pixels are nearer than {nearest_depth:.2f} m, the nearest depth "
            "disparity_range can see: they are left out of depth and points2 (near_points: range_limit puts "
            "them in points2 at that depth); a larger disparity_range, or downsample, sees nearer"
        )

    def add_dropped(self, count: int) -> None:
        with self._lock:
            self.dropped += count

    def frame_dropped(self, late: bool) -> None:
        """A set the worker never processed: replaced by newer ones, or `late` for max_latency_ms."""
        with self._lock:
            self.dropped += 1
            self.dropped_late += late

    def cloud_dropped(self, late: bool) -> None:
        with self._lock:
            self.dropped_clouds += 1
            self.dropped_late += late

    def output_age(self, output: str, age_s: float) -> None:
        with self._lock:
            self._age_s.setdefault(output, deque(maxlen=RECENT_FRAMES)).append(age_s)

    def error(self, text: str) -> None:
        with self._lock:
            self.last_error = text
            self._last_error_at = time.monotonic()

    def calibration(self, stamp_ns: int, check: CalibrationCheck) -> None:
        with self._lock:
            self._calibration = (stamp_ns, check)

    def report(self, header: object) -> DiagnosticArray:
        """Rates over the last seconds; times are means over the last RECENT_FRAMES frames."""
        now = time.monotonic()
        with self._lock:
            values = self._values(now)
            level, message = self._level(now)
            calibration = self._calibration
        status = DiagnosticStatus(
            level=level,
            name=f"{self._name}: stereo processing",
            message=message,
            hardware_id=self._name,
            values=[KeyValue(key=k, value=v) for k, v in values],
        )
        statuses = [status]
        if calibration is not None:
            statuses.append(self._calibration_status(*calibration))
        return DiagnosticArray(header=header, status=statuses)

    def _calibration_status(self, stamp_ns: int, check: CalibrationCheck) -> DiagnosticStatus:
        values = [
            ("median vertical offset (px)", f"{check.median_dy:.3f}"),
            ("inlier matches", str(check.inliers)),
            ("frame stamp (ns)", str(stamp_ns)),
        ]
        return DiagnosticStatus(
            level=bytes([int(check.level)]),
            name=f"{self._name}: calibration",
            message=check.message,
            hardware_id=self._name,
            values=[KeyValue(key=k, value=v) for k, v in values],
        )

    def _values(self, now: float) -> list[tuple[str, str]]:
        values = []
        for topic, monitor in self.inputs.items():
            values.append((f"{topic} rate (Hz)", f"{monitor.received_hz(now):.2f}"))
            values.append((f"{topic} sender rate from stamps (Hz)", f"{monitor.sender_hz():.2f}"))
            values.append((f"{topic} missing (recent window)", str(monitor.missing())))
            values.append((f"{topic} lost (DDS)", str(monitor.lost_reported)))
            values.append((f"{topic} unmatched", str(monitor.unmatched)))
            in_dds = self._in_dds_ms.get(topic)
            if in_dds:
                values.append((f"{topic} time in DDS (ms, median / max)", f"{median(in_dds):.1f} / {max(in_dds):.1f}"))
            if monitor.substituted or monitor.late:
                values.append((f"{topic} missing, last one used", str(monitor.substituted)))
                values.append((f"{topic} late (after its set)", str(monitor.late)))
        outputs = [t for t in self._outputs if now - t <= 2.0]
        rate = (len(outputs) - 1) / max(outputs[-1] - outputs[0], 1e-9) if len(outputs) > 1 else 0.0
        values.append(("output rate (Hz)", f"{rate:.2f}"))
        for stage in (*STAGES, *sorted(set(self._stage_ms) - set(STAGES))):
            samples = self._stage_ms.get(stage)
            if samples:
                values.append((f"{stage} time (ms)", f"{sum(samples) / len(samples):.2f}"))
        if self._latency_s:
            values.append(("latency from stamp (s)", f"{sum(self._latency_s) / len(self._latency_s):.3f}"))
        for output, ages in sorted(self._age_s.items()):
            values.append((f"{output} age at publish (ms)", f"{1000.0 * sum(ages) / len(ages):.1f}"))
        if self._too_near:
            share = sum(self._too_near) / len(self._too_near)
            values.append(("too near for disparity_range (share of pixels)", f"{share:.3f}"))
            values.append(("nearest matchable depth (m)", f"{self._nearest_depth:.3f}"))
        values.append(("frames processed", str(self.processed)))
        values.append(("dropped frames", str(self.dropped)))
        values.append(("dropped clouds (depth, points2)", str(self.dropped_clouds)))
        values.append(("dropped as too late for max_latency_ms (frames and clouds)", str(self.dropped_late)))
        values.append(("unmatched input messages", str(self.unmatched)))
        values.append(
            ("sets without calibration (none yet, or it changed where one was lost)", str(self.calibration_unknown))
        )
        values.append(("bottleneck", self._bottleneck()))
        values.append(("stale or repeated stamps", str(self.stale)))
        values.append(("time jumps (pairing restarted)", str(self.time_jumps)))
        values.append(("calibrations loaded", str(self.calibrations)))
        if self.without_colour is not None:
            values.append(("frames without a colour image (registered outputs)", str(self.without_colour)))
        values.append(("silent inputs", self._silence(now) or "none"))
        values.append(("last error", self.last_error or "none"))
        return values

    def _level(self, now: float) -> tuple[bytes, str]:
        if self.last_error and now - self._last_error_at <= 5.0:
            return DiagnosticStatus.WARN, f"frames skipped: {self.last_error}"
        silence = self._silence(now)
        if silence:
            return DiagnosticStatus.WARN, silence
        lossy = [t for t, m in self.inputs.items() if m.missing()]
        if lossy:
            return DiagnosticStatus.WARN, f"inputs arrive slower than sent: {', '.join(lossy)}; {LOSS_HELP}"
        return DiagnosticStatus.OK, "ok"

    def _bottleneck(self) -> str:
        """Where frames were lost since the previous report: inputs (per topic), matching (sets replaced
        before the worker took them), or the cloud stage (depth/points2 replaced); the worst named first."""
        counts = {
            f"input {t} (lost in DDS, unmatched or stood in for)": m.lost_reported + m.unmatched + m.substituted
            for t, m in self.inputs.items()
        }
        counts["matching slower than the input (dropped frames)"] = self.dropped
        counts["depth/points2 stage slower than the input (dropped clouds; see the publish points2 time)"] = (
            self.dropped_clouds
        )
        grown = {what: n - self._reported.get(what, 0) for what, n in counts.items()}
        self._reported = counts
        worst = sorted((n, what) for what, n in grown.items() if n > 0)
        if not worst:
            return "none"
        return "; ".join(f"{what}: {n}" for n, what in reversed(worst)) + f"; {BOTTLENECK_HELP}"
