"""Results into a rosbag2 that appears under its final name only when it is complete.

rosbags' `Writer.__exit__` writes metadata.yaml even when the block raised, so a failed run would leave
a bag that looks whole. `BagWriter` writes into an `AtomicFolder` (a hidden folder beside the target,
published in one rename) and aborts the writer on any error, Ctrl-C included.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import Any, Literal

from rosbags.interfaces import Connection
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag1 import WriterError as Ros1WriterError
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from stereo_depth.atomic_output import AtomicFolder, check_output
from stereo_depth.bag.types import serialize, typestore
from stereo_depth.errors import BagError

__all__ = ["STORAGES", "BagWriter", "check_output"]

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
ROS1 = "rosbag1"  # a ROS 1 .bag file, for make-bag (tests and users who need one); results stay rosbag2
BAG_VERSION: Literal[9] = 9  # what Jazzy's rosbag2 writes


class BagWriter:
    """Write messages to named topics; connections are added on a topic's first message."""

    def __init__(
        self,
        path: Path | str,
        *,
        storage: str = "mcap",
        overwrite: bool = False,
        compress: bool = True,
        custom_data: dict[str, str] | None = None,
    ) -> None:
        if storage not in STORAGES and storage != ROS1:
            msg = f"storage '{storage}' is unknown; choose one of {sorted([*STORAGES, ROS1])}"
            raise BagError(msg)
        self.path = Path(path)
        self.storage = storage
        self.overwrite = overwrite
        self.compress = compress and storage == "mcap"  # zstd chunks; ros2 bag play reads them natively
        self._folder: AtomicFolder | None = None
        self._writer: Writer | Ros1Writer | None = None
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        self.custom_data = dict(custom_data or {})  # metadata.yaml custom_data: written with the bag, at once

    def __enter__(self) -> BagWriter:
        self._folder = AtomicFolder(self.path, overwrite=self.overwrite, is_file=self.storage == ROS1)
        staging = self._folder.__enter__()
        writer = self._new_writer(staging)
        try:
            writer.open()
        except (WriterError, Ros1WriterError) as exc:
            self._folder.__exit__(type(exc), exc, None)
            msg = f"cannot create bag {self.path}: {exc}"
            raise BagError(msg) from exc
        self._writer = writer
        return self

    def _new_writer(self, path: Path) -> Writer | Ros1Writer:
        if self.storage == ROS1:
            return Ros1Writer(path)
        writer = Writer(path, version=BAG_VERSION, storage_plugin=STORAGES[self.storage])
        if self.compress:
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in self.custom_data.items():
            writer.set_custom_data(key, value)
        return writer

    def write(self, topic: str, message: Any, timestamp_ns: int) -> None:
        self.write_raw(topic, message.__msgtype__, serialize(message), timestamp_ns)

    def write_raw(self, topic: str, msgtype: str, raw: bytes | memoryview, timestamp_ns: int) -> None:
        """One message already serialized as Jazzy CDR, e.g. copied from another bag."""
        assert self._writer is not None, "use BagWriter as a context manager"
        connection = self._connections.get(topic)
        if connection is None:
            store = get_typestore(Stores.ROS1_NOETIC) if isinstance(self._writer, Ros1Writer) else typestore()
            connection = self._writer.add_connection(topic, msgtype, typestore=store)
            self._connections[topic] = connection
            self.counts[topic] = 0
        if isinstance(self._writer, Ros1Writer):  # Jazzy's CDR -> ROS 1 bytes (header.seq 0)
            raw = typestore().cdr_to_ros1(bytes(raw), msgtype)
        self._writer.write(connection, timestamp_ns, raw)
        self.counts[topic] += 1

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        writer, self._writer = self._writer, None
        if writer is None or self._folder is None:
            return False
        if exc_type is not None:
            writer.abort()
            return self._folder.__exit__(exc_type, exc, tb)
        try:
            writer.close()
        except BaseException as error:
            self._folder.__exit__(type(error), error, error.__traceback__)
            raise
        return self._folder.__exit__(None, None, None)
