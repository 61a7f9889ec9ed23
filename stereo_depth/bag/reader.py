"""Stereo frames out of a rosbag2 (MCAP or sqlite3), paired with the live node's sync rules.

The stereo topics are found by their suffixes (`left/image_raw`, `left/camera_info`, `right/image_raw`,
`right/camera_info`, or the `image_rect` variants) so that a bag recorded under any namespace works
without naming four topics; a namespace is only needed when the bag holds several stereo sets.
Messages go through `sync.Synchronizer` in the order they were recorded, as they would arrive live.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

from rosbags.rosbag2 import Reader, ReaderError

from stereo_depth.bag.types import deserialize
from stereo_depth.errors import BagError
from stereo_depth.messages import stamp_to_ns
from stereo_depth.sync import SyncCounters, Synchronizer

ROLES = ("left_image", "left_info", "right_image", "right_info")
SUFFIXES = {
    "image_raw": ("left/image_raw", "left/camera_info", "right/image_raw", "right/camera_info"),
    "image_rect": ("left/image_rect", "left/camera_info", "right/image_rect", "right/camera_info"),
}
NO_LIMIT_NS = 1 << 62
IMAGE_TYPE = "sensor_msgs/msg/Image"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"


@dataclass(frozen=True)
class StereoTopics:
    namespace: str  # "" or "/ns", without a trailing slash
    names: tuple[str, str, str, str]  # in ROLES order
    rectified: bool

    def output(self, name: str) -> str:
        """An output topic under the same namespace as the input (e.g. /stereo/disparity)."""
        return f"{self.namespace}/{name}"


@dataclass(frozen=True)
class SyncPolicy:
    """The live node's sync parameters and defaults (queue_size, approximate_sync and its tolerance)."""

    approximate: bool = False
    queue_size: int = 5
    tolerance_ns: int = NO_LIMIT_NS

    @classmethod
    def from_node_parameters(cls, approximate: bool, queue_size: int, tolerance_s: float) -> SyncPolicy:
        """As the node reads approximate_sync_tolerance_seconds: 0 means no limit (stereo_image_proc)."""
        return cls(approximate, queue_size, round(tolerance_s * 1e9) if tolerance_s > 0 else NO_LIMIT_NS)


@dataclass(frozen=True)
class TimeWindow:
    """The sets one shard of a long bag owns: set stamps in [start_ns, stop_ns) (None: unbounded).

    Reading starts `lead_ns` of recording time before `start_ns` so the synchronizer holds what one
    pass over the whole bag would hold at the border, and goes on past `stop_ns` (at most `lead_ns`)
    until the first set of the next window is paired: its stamp (`ReadStats.handoff_ns`) must be the
    next shard's first (`ReadStats.first_ns`), which is how a border is checked to pair as one pass does.
    """

    start_ns: int | None = None
    stop_ns: int | None = None
    lead_ns: int = 2_000_000_000

    def owns(self, stamp_ns: int) -> bool:
        return (self.start_ns is None or stamp_ns >= self.start_ns) and (
            self.stop_ns is None or stamp_ns < self.stop_ns
        )


@dataclass
class StereoMessages:
    """One matched set of the four inputs, as deserialized messages."""

    stamp_ns: int
    left_image: Any
    left_info: Any
    right_image: Any
    right_info: Any


def _normalise(namespace: str) -> str:
    return "/" + namespace.strip("/") if namespace.strip("/") else ""


def _sets(topics: dict[str, str]) -> list[StereoTopics]:
    """Every (namespace, raw|rect) for which the bag has all four topics with the right types."""
    found = []
    for variant, suffixes in SUFFIXES.items():
        for name in topics:
            if not name.endswith("/" + suffixes[0]):
                continue
            namespace = name[: -len(suffixes[0]) - 1]
            names = tuple(f"{namespace}/{suffix}" for suffix in suffixes)
            wanted = (IMAGE_TYPE, INFO_TYPE, IMAGE_TYPE, INFO_TYPE)
            if all(topics.get(n) == t for n, t in zip(names, wanted, strict=True)):
                found.append(StereoTopics(namespace, names, variant == "image_rect"))  # type: ignore[arg-type]
    return found


def _wrong_types(topics: dict[str, str]) -> str:
    """'; but X is T, not Image' for stereo-named topics of another type (compressed images, mostly)."""
    expected = {suffix: IMAGE_TYPE if "image" in suffix else INFO_TYPE for s in SUFFIXES.values() for suffix in s}
    wrong = [
        f"{name} is {kind}, not {want}"
        for name, kind in sorted(topics.items())
        for suffix, want in expected.items()
        if name.endswith("/" + suffix) and kind != want
    ]
    if not wrong:
        return ""
    return f"; but {'; '.join(wrong)} (decompress compressed images first, e.g. image_transport republish)"


def find_stereo_topics(topics: dict[str, str], namespace: str | None = None) -> StereoTopics:
    """The stereo set in a bag's {topic: msgtype}; raw images win over rectified ones in one namespace."""
    candidates = _sets(topics)
    if namespace is not None:
        candidates = [c for c in candidates if c.namespace == _normalise(namespace)]
    namespaces = sorted({c.namespace or "/" for c in candidates})
    if not candidates:
        where = f" under namespace '{_normalise(namespace) or '/'}'" if namespace is not None else ""
        msg = (
            f"the bag has no complete stereo topic set{where} (…/left/image_raw, …/left/camera_info, "
            f"…/right/image_raw, …/right/camera_info, or image_rect); "
            f"it has: {', '.join(sorted(topics)) or 'no topics'}{_wrong_types(topics)}"
        )
        raise BagError(msg)
    if len(namespaces) > 1:
        msg = (
            f"the bag holds stereo topics under several namespaces ({', '.join(namespaces)}); "
            "choose one with --namespace"
        )
        raise BagError(msg)
    return min(candidates, key=lambda c: c.rectified)


@dataclass
class ReadStats:
    """What happened to the input: enough to tell a user why frames are missing."""

    left_images: int = 0
    right_images: int = 0
    matched: int = 0
    sync: SyncCounters | None = None
    unmatched_at_end: int = 0
    first_ns: int | None = None  # stamp of the first set yielded (a window's first)
    handoff_ns: int | None = None  # with a window: stamp of the first set after it (None: the bag ended)


class StereoBagReader:
    """Open a bag, find its stereo topics and yield matched sets; use as a context manager."""

    def __init__(
        self,
        path: Path | str,
        *,
        namespace: str | None = None,
        sync: SyncPolicy | None = None,
        window: TimeWindow | None = None,
    ) -> None:
        self.path = Path(path)
        self.policy = sync or SyncPolicy()
        self.window = window or TimeWindow()
        self._reader = open_reader(self.path)
        try:
            self.topics = find_stereo_topics(self.topic_types(), namespace)
        except BagError:
            self._reader.close()
            raise
        self.stats = ReadStats()

    def topic_types(self) -> dict[str, str]:
        return {c.topic: c.msgtype for c in self._reader.connections}

    def count(self, topic: str) -> int:
        return sum(c.msgcount for c in self._reader.connections if c.topic == topic)

    def __enter__(self) -> StereoBagReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        self._reader.close()
        return False

    def frames(self) -> Iterator[StereoMessages]:
        """Matched sets in recording order; counts in `stats` what could not be paired."""
        sync = Synchronizer(len(ROLES), self.policy.queue_size, self.policy.approximate, self.policy.tolerance_ns)
        self.stats.sync = sync.counters
        role_of = {name: i for i, name in enumerate(self.topics.names)}
        window = self.window
        for topic, message in self._messages(list(role_of)):
            role = role_of[topic]
            stamp_ns = stamp_to_ns(message.header.stamp)
            if window.owns(stamp_ns):
                self._count_input(role)
            for stamp, msgs in sync.add(role, stamp_ns, message):
                if window.stop_ns is not None and stamp >= window.stop_ns:
                    self.stats.handoff_ns = stamp  # set stamps only grow: the window is complete
                    self.stats.unmatched_at_end = sync.pending()
                    return
                if not window.owns(stamp):
                    continue  # lead-in: paired only to reach one pass's state at the border
                self.stats.matched += 1
                if self.stats.first_ns is None:
                    self.stats.first_ns = stamp
                yield StereoMessages(stamp, *msgs)
        self.stats.unmatched_at_end = sync.pending()

    def _messages(self, topics: list[str]) -> Iterator[tuple[str, Any]]:
        """(topic, message) in recording order. Damage found while reading (a cut-off file, a corrupt
        compressed chunk or database page, undecodable CDR) becomes one BagError naming the file,
        whichever library noticed it: rosbags, zstd, apsw and the CDR decoder each raise their own."""
        connections = [c for c in self._reader.connections if c.topic in topics]
        start, stop = self.window.start_ns, self.window.stop_ns
        messages = self._reader.messages(
            connections=connections,
            start=None if start is None else start - self.window.lead_ns,
            stop=None if stop is None else stop + self.window.lead_ns,
        )
        while True:
            try:
                item = next(messages, None)
                if item is None:
                    return
                connection, _, raw = item
                message = deserialize(raw, connection.msgtype)
            except Exception as exc:
                msg = (
                    f"{self.path}: cannot read messages ({type(exc).__name__}: {exc}); the bag is truncated or "
                    "damaged: record it again, or repair a copy (mcap recover, ros2 bag reindex)"
                )
                raise BagError(msg) from exc
            yield connection.topic, message

    def _count_input(self, role: int) -> None:
        if role == 0:
            self.stats.left_images += 1
        elif role == 2:
            self.stats.right_images += 1


def open_reader(path: Path) -> Reader:
    """A rosbags Reader, or a BagError that says what to pass instead."""
    if path.is_file() and path.suffix in (".mcap", ".db3"):
        msg = f"{path} is a storage file; pass its bag folder (the one with metadata.yaml): {path.parent}"
        raise BagError(msg)
    if not path.exists():
        msg = f"{path} does not exist; pass a rosbag2 folder (with metadata.yaml)"
        raise BagError(msg)
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError) as exc:
        msg = (
            f"{path}: not a readable rosbag2 ({exc}); pass a folder made by ros2 bag record or stereo-depth "
            "make-bag (a recording cut short may be repaired on a copy with mcap recover or ros2 bag reindex)"
        )
        raise BagError(msg) from exc
    return reader


def read_messages(path: Path | str, topics: list[str]) -> dict[str, list[Any]]:
    """Every message on `topics`, deserialized, in recording order (for checks and small bags)."""
    reader = open_reader(Path(path))
    try:
        missing = sorted(set(topics) - {c.topic for c in reader.connections})
        if missing:
            have = ", ".join(sorted({c.topic for c in reader.connections}))
            msg = f"{path} has no topic {', '.join(missing)}; it has: {have}"
            raise BagError(msg)
        out: dict[str, list[Any]] = {t: [] for t in topics}
        connections = [c for c in reader.connections if c.topic in out]
        for connection, _, raw in reader.messages(connections=connections):
            out[connection.topic].append(deserialize(raw, connection.msgtype))
        return out
    finally:
        reader.close()
