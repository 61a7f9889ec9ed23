"""A long bag as time windows processed at once, joined back into one bag in stamp order.

Each window owns the sets whose stamp falls inside it (`bag.reader.TimeWindow`), so no frame is lost
or doubled at a border; its reader starts early enough for the synchronizer to pair across the
border as one pass does, and `check_borders` verifies that it did before the parts are joined.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

from stereo_depth.bag.reader import TimeWindow
from stereo_depth.bag.recording import open_reader
from stereo_depth.bag.writer import BagWriter
from stereo_depth.errors import BagError
from stereo_depth.fleet.tasks import TaskResult


def windows(bag: Path, shard_seconds: float) -> list[TimeWindow]:
    """Windows of `shard_seconds` of recording time; the first and last are open-ended, so a stamp
    outside the recorded span still belongs to exactly one window."""
    reader = open_reader(bag)
    try:
        start, end = reader.time_span
    finally:
        reader.close()
    step = round(shard_seconds * 1e9)
    count = max(1, math.ceil((end - start) / step)) if end > start else 1
    borders: list[int | None] = [None, *(start + k * step for k in range(1, count)), None]
    return [TimeWindow(borders[k], borders[k + 1]) for k in range(count)]


def check_borders(name: str, parts: list[TaskResult]) -> None:
    """Each window's reader went on past its end to the first set of the next window; the next
    window's reader, started early, must have paired that same set first. Otherwise the border was
    paired differently from one pass (a recording gap or latency longer than the lead-in)."""
    for before, after in itertools.pairwise(parts):
        if before.handoff_ns is not None and before.handoff_ns != after.first_ns:
            msg = (
                f"{name}: the shard border before stamp {before.handoff_ns} paired frames differently from one "
                "pass; process this bag without --shard-seconds or with longer shards"
            )
            raise BagError(msg)


def merge(
    parts: list[Path], out_bag: Path, *, storage: str, compress: bool, overwrite: bool, custom_data: dict[str, str]
) -> None:
    """The parts' messages, part after part in their recorded order, into one bag (atomically). A stamp
    that an earlier part wrote on the same topic is refused: a frame written twice is a border bug."""
    earlier: set[tuple[str, int]] = set()
    with BagWriter(out_bag, storage=storage, compress=compress, overwrite=overwrite, custom_data=custom_data) as writer:
        for part in parts:
            written = set()
            reader = open_reader(part, allow_empty=True)  # a shard may own no frame
            try:
                for connection, timestamp, raw in reader.messages(reader.connections):
                    if (connection.topic, timestamp) in earlier:
                        msg = (
                            f"two shards wrote {connection.topic} at stamp {timestamp}: that frame would be there "
                            "twice; process this bag without --shard-seconds"
                        )
                        raise BagError(msg)
                    written.add((connection.topic, timestamp))
                    writer.write_raw(connection.topic, connection.msgtype, raw, timestamp)
            finally:
                reader.close()
            earlier |= written
