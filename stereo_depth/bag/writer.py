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
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer, WriterError

from stereo_depth.atomic_output import AtomicFolder, check_output
from stereo_depth.bag.types import serialize, typestore
from stereo_depth.errors import BagError

__all__ = ["STORAGES", "BagWriter", "check_output"]

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
BAG_VERSION: Literal[9] = 9  # what Jazzy's rosbag2 writes


class BagWriter:
    """Write messages to named topics; connections are added on a topic's first message."""

    def __init__(
        self, path: Path | str, *, storage: str = "mcap", overwrite: bool = False, compress: bool = True
    ) -> None:
        if storage not in STORAGES:
            msg = f"storage '{storage}' is unknown; choose one of {sorted(STORAGES)}"
            raise BagError(msg)
        self.path = Path(path)
        self.storage = storage
        self.overwrite = overwrite
        self.compress = compress and storage == "mcap"  # zstd chunks; ros2 bag play reads them natively
        self._folder: AtomicFolder | None = None
        self._writer: Writer | None = None
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    def __enter__(self) -> BagWriter:
        self._folder = AtomicFolder(self.path, overwrite=self.overwrite)
        staging = self._folder.__enter__()
        writer = Writer(staging, version=BAG_VERSION, storage_plugin=STORAGES[self.storage])
        if self.compress:
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        try:
            writer.open()
        except WriterError as exc:
            self._folder.__exit__(type(exc), exc, None)
            msg = f"cannot create bag {self.path}: {exc}"
            raise BagError(msg) from exc
        self._writer = writer
        return self

    def write(self, topic: str, message: Any, timestamp_ns: int) -> None:
        assert self._writer is not None, "use BagWriter as a context manager"
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._writer.add_connection(topic, message.__msgtype__, typestore=typestore())
            self._connections[topic] = connection
            self.counts[topic] = 0
        self._writer.write(connection, timestamp_ns, serialize(message))
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
