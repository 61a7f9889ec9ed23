"""stereo_node with a per-frame timeline, for `bench/e2e_dds.py --timeline`: where a disparity's latency goes.

Run as `python -m lib.timeline_node` (bench/ on PYTHONPATH) in place of stereo_depth.nodes.stereo_node. For each
input stamp it records, in the system clock's ns (the clock of DDS's sample timestamps and of e2e_dds's
monitor): each input's DDS reception, its callback's start and end, the worker's start on the set, and
the start and end of each output's publish(). At exit it writes them as JSON to $STEREO_DEPTH_TIMELINE.
"""

from __future__ import annotations

import atexit
import json
import os
import struct
import threading
import time
from pathlib import Path
from typing import Any

from stereo_depth.messages import SerializedMessage, stamp_to_ns
from stereo_depth.nodes.stereo_node import StereoNode
from stereo_depth.ros.input_pairing import InputPairing
from stereo_depth.ros.node_base import FrameJob
from stereo_depth.ros.node_main import run_node

_EVENTS: dict[int, dict[str, int]] = {}  # input stamp -> event -> system clock ns
_LOCK = threading.Lock()


def stamp_of(message: Any) -> int:
    """The header stamp of a message, also of one the node publishes as its CDR bytes (little-endian; the
    header comes first, after the 4-byte encapsulation: sec int32, nanosec uint32)."""
    if isinstance(message, SerializedMessage):
        sec, nanosec = struct.unpack_from("<iI", message.buffer, 4)
        return int(sec) * 1_000_000_000 + int(nanosec)
    return stamp_to_ns(message.header.stamp)


def record(stamp_ns: int, event: str, at_ns: int | None = None) -> None:
    with _LOCK:
        _EVENTS.setdefault(stamp_ns, {})[event] = time.time_ns() if at_ns is None else at_ns


def _recorded_on_message(pairing: InputPairing, index: int, msg: Any, sample: dict[str, int] | None) -> None:
    stamp = stamp_to_ns(msg.header.stamp)
    record(stamp, f"callback {index}")
    if sample and sample.get("received_timestamp"):
        record(stamp, f"dds {index}", sample["received_timestamp"])
    _on_message(pairing, index, msg, sample)
    record(stamp, f"callback end {index}")


_on_message = InputPairing._on_message
setattr(InputPairing, "_on_message", _recorded_on_message)  # noqa: B010 (each input's callback, timed)


class TimelineNode(StereoNode):
    def _run_frame(self, job: FrameJob) -> None:
        record(job.stamp_ns, "worker")
        super()._run_frame(job)

    def publish_outputs(self, messages: dict[str, Any], stages: dict[str, float], received_s: float) -> None:
        for name, message in messages.items():
            stamp = stamp_of(message)
            record(stamp, f"publish {name}")
            super().publish_outputs({name: message}, stages, received_s)
            record(stamp, f"published {name}")


def _write() -> None:
    with _LOCK:
        Path(os.environ["STEREO_DEPTH_TIMELINE"]).write_text(json.dumps(_EVENTS))


if __name__ == "__main__":
    atexit.register(_write)
    raise SystemExit(run_node(TimelineNode))
