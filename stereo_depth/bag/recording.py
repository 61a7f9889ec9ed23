"""A recording on disk, ROS 1 bag or rosbag2 (MCAP, sqlite3), read as ROS 2 Jazzy CDR either way.

ROS 1 bags (EuRoC, TUM-VI, KITTI via kitti2bag and most public datasets) need no ROS 1 install:
rosbags reads them, and each message's ROS 1 bytes become the CDR bytes a Jazzy publisher would send
(`header.seq` dropped, CameraInfo's D/K/R/P read as d/k/r/p: same wire layout). Types whose layout
changed between ROS 1 and ROS 2 are migrated field by field, as `rosbags-convert` does. Everything after
this module (deserialize, replay's raw publish) sees one kind of bag.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from functools import partial
from pathlib import Path

from rosbags.convert.converter import is_same_wireformat, migrate_bytes
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.typesys.store import Typestore

from stereo_depth.bag.types import typestore
from stereo_depth.errors import BagError

RawMessage = tuple[Connection, int, bytes | memoryview]  # connection, bag time (ns), Jazzy CDR
ROS1_MAGIC = b"#ROSBAG V2.0"  # the first bytes of every ROS 1 bag file
ROS2_METADATA = "metadata.yaml"


def is_ros1_bag(path: Path) -> bool:
    """A bag is told by its content, not its name: a file that starts as ROS 1 bags do is one (a
    rosbag2 is a folder, whatever it is called: `ros2 bag record -o run.bag` makes a folder `run.bag/`)."""
    if not path.is_file():
        return False
    with path.open("rb") as file:
        return file.read(len(ROS1_MAGIC)) == ROS1_MAGIC


class Recording:
    """Connections and messages of one bag; open with `open_reader`, close when done."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.is_ros1 = is_ros1_bag(path)
        self._ros1: AnyReader | None = None
        self._ros2: Reader | None = None
        self._to_cdr: dict[str, Callable[[bytes | memoryview], bytes | memoryview]] = {}
        if self.is_ros1:
            self._ros1 = AnyReader([path], default_typestore=typestore())
            self._ros1.open()
        else:
            self._ros2 = Reader(path)
            self._ros2.open()

    @property
    def connections(self) -> list[Connection]:
        reader = self._ros1 or self._ros2
        assert reader is not None
        return list(reader.connections)

    @property
    def message_count(self) -> int:
        return sum(c.msgcount for c in self.connections)

    @property
    def time_span(self) -> tuple[int, int]:
        """(first, last) recording time in ns, from the bag's index: no message is read."""
        reader = self._ros1 or self._ros2
        assert reader is not None
        return reader.start_time, reader.end_time

    def messages(
        self, connections: Sequence[Connection], start: int | None = None, stop: int | None = None
    ) -> Iterator[RawMessage]:
        """Messages of `connections` in recording order, as Jazzy CDR; recorded in [start, stop) ns if given."""
        if self._ros2 is not None:
            yield from self._ros2.messages(connections=connections, start=start, stop=stop)
            return
        assert self._ros1 is not None
        for connection, timestamp, raw in self._ros1.messages(connections=connections, start=start, stop=stop):
            yield connection, timestamp, self._converter(connection.msgtype)(raw)

    def _converter(self, msgtype: str) -> Callable[[bytes | memoryview], bytes | memoryview]:
        """ROS 1 bytes -> Jazzy CDR for one type, chosen once per type."""
        convert = self._to_cdr.get(msgtype)
        if convert is None:
            assert self._ros1 is not None
            convert = ros1_to_jazzy(self._ros1.typestore, msgtype)
            self._to_cdr[msgtype] = convert
        return convert

    def close(self) -> None:
        for reader in (self._ros1, self._ros2):
            if reader is not None:
                reader.close()


def ros1_to_jazzy(source_store: Typestore, msgtype: str) -> Callable[[bytes | memoryview], bytes | memoryview]:
    """A function from a ROS 1 message's bytes (types as the bag defines them) to Jazzy's CDR."""
    jazzy = typestore()
    if msgtype not in jazzy.fielddefs:
        msg = f"message type {msgtype} (ROS 1) has no ROS 2 Jazzy counterpart to read it as"
        raise BagError(msg)
    if is_same_wireformat(source_store, jazzy, msgtype, msgtype):
        return partial(jazzy.ros1_to_cdr, typename=msgtype)
    return partial(migrate_bytes, source_store, jazzy, msgtype, msgtype, {}, src_is2=False, dst_is2=True)


def open_reader(path: Path, *, allow_empty: bool = False) -> Recording:
    """A Recording, or a BagError that says what to pass instead. `allow_empty`: a bag without messages
    is fine (a shard that owned no frame), not an error."""
    if path.is_file() and path.suffix in (".mcap", ".db3"):
        msg = f"{path} is a storage file; pass its bag folder (the one with metadata.yaml): {path.parent}"
        raise BagError(msg)
    if not path.exists():
        msg = f"{path} does not exist; pass a rosbag2 folder (with metadata.yaml) or a ROS 1 .bag file"
        raise BagError(msg)
    if path.is_file() and not is_ros1_bag(path):
        msg = (
            f"{path} is a file but not a ROS 1 bag (it does not start with {ROS1_MAGIC.decode()}); pass a ROS 1 "
            "bag file or a rosbag2 folder (with metadata.yaml)"
        )
        raise BagError(msg)
    if path.is_dir() and not (path / ROS2_METADATA).is_file():
        msg = (
            f"{path} is a folder without {ROS2_METADATA}, so not a rosbag2; pass the folder made by ros2 bag record "
            "or stereo-depth make-bag (a recording cut short may get its metadata.yaml back with ros2 bag reindex)"
        )
        raise BagError(msg)
    try:
        recording = Recording(path)
    except (ReaderError, Ros1ReaderError, AnyReaderError, OSError) as exc:
        if path.is_file():
            msg = f"{path}: not a readable ROS 1 bag ({exc}); a recording cut short may be repaired with rosbag reindex"
        else:
            msg = (
                f"{path}: not a readable rosbag2 ({exc}); pass a folder made by ros2 bag record or stereo-depth "
                "make-bag, or a ROS 1 .bag file (a recording cut short may be repaired on a copy with mcap "
                "recover or ros2 bag reindex)"
            )
        raise BagError(msg) from exc
    if recording.message_count == 0 and not allow_empty:
        topics = ", ".join(sorted({c.topic for c in recording.connections})) or "no topics"
        recording.close()
        msg = f"{path} holds no messages ({topics}); record again, with the cameras publishing"
        raise BagError(msg)
    return recording
