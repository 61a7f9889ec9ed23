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
from stereo_depth.ros.stereo_io import run_node

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


class TimelineNode(StereoNode):
    def _on_message(self, index: int, msg: Any, sample: dict[str, int] | None) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        record(stamp, f"callback {index}")
        if sample and sample.get("received_timestamp"):
            record(stamp, f"dds {index}", sample["received_timestamp"])
        super()._on_message(index, msg, sample)
        record(stamp, f"callback end {index}")

    def _run_frame(self, job: tuple[int, int, float, tuple[Any, ...]]) -> None:
        record(job[1], "worker")
        super()._run_frame(job)

    def _publish(self, messages: dict[str, Any], stages: dict[str, float]) -> None:
        for name, message in messages.items():
            stamp = stamp_of(message)
            record(stamp, f"publish {name}")
            super()._publish({name: message}, stages)
            record(stamp, f"published {name}")


def _write() -> None:
    with _LOCK:
        Path(os.environ["STEREO_DEPTH_TIMELINE"]).write_text(json.dumps(_EVENTS))


if __name__ == "__main__":
    atexit.register(_write)
    raise SystemExit(run_node(TimelineNode))
