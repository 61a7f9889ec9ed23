"""Results into a rosbag2 that appears under its final name only when it is complete.

rosbags' `Writer.__exit__` writes metadata.yaml even when the block raised, so a failed run would leave
a bag that looks whole. `BagWriter` writes into `<parent>/.<name>.<random>/<name>/` (same filesystem,
so the final step is one rename) and deletes that folder on any error, Ctrl-C included.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

from rosbags.interfaces import Connection
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer, WriterError

from stereo_depth.bag.types import serialize, typestore
from stereo_depth.errors import BagError

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
BAG_VERSION: Literal[9] = 9  # what Jazzy's rosbag2 writes


def check_output(path: Path, overwrite: bool) -> None:
    """Refuse before any work is done, so a long run does not fail at its end."""
    if path.exists() and not overwrite:
        msg = f"{path} exists already; choose another output name or pass --overwrite"
        raise BagError(msg)
    if not path.parent.is_dir():
        msg = f"{path.parent} is not a folder; create it first"
        raise BagError(msg)
    if not os.access(path.parent, os.W_OK | os.X_OK):
        msg = f"cannot write in {path.parent} (permission denied); choose an output folder you can write to"
        raise BagError(msg)


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
        if storage not in STORAGES:
            msg = f"storage '{storage}' is unknown; choose one of {sorted(STORAGES)}"
            raise BagError(msg)
        self.path = Path(path)
        self.storage = storage
        self.overwrite = overwrite
        self.compress = compress and storage == "mcap"  # zstd chunks; ros2 bag play reads them natively
        self._tmp: Path | None = None
        self._writer: Writer | None = None
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        self.custom_data = dict(custom_data or {})  # metadata.yaml custom_data: written with the bag, at once

    def __enter__(self) -> BagWriter:
        check_output(self.path, self.overwrite)
        try:
            self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
        except OSError as exc:  # read-only file system, or a permission os.access did not foresee
            msg = f"cannot write in {self.path.parent} ({exc.strerror}); choose an output folder you can write to"
            raise BagError(msg) from exc
        writer = Writer(self._tmp / self.path.name, version=BAG_VERSION, storage_plugin=STORAGES[self.storage])
        if self.compress:
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in self.custom_data.items():
            writer.set_custom_data(key, value)
        try:
            writer.open()
        except WriterError as exc:
            self._discard()
            msg = f"cannot create bag {self.path}: {exc}"
            raise BagError(msg) from exc
        self._writer = writer
        return self

    def write(self, topic: str, message: Any, timestamp_ns: int) -> None:
        self.write_raw(topic, message.__msgtype__, serialize(message), timestamp_ns)

    def write_raw(self, topic: str, msgtype: str, raw: bytes | memoryview, timestamp_ns: int) -> None:
        """One message already serialized (CDR), e.g. copied from another bag."""
        assert self._writer is not None, "use BagWriter as a context manager"
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._writer.add_connection(topic, msgtype, typestore=typestore())
            self._connections[topic] = connection
            self.counts[topic] = 0
        self._writer.write(connection, timestamp_ns, raw)
        self.counts[topic] += 1

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        writer, self._writer = self._writer, None
        if writer is None:
            return False
        if exc_type is not None:
            writer.abort()
            self._discard()
            return False
        try:
            writer.close()
            self._publish()
        except BaseException:
            self._discard()
            raise
        return False

    def _publish(self) -> None:
        """Move the finished bag to its final name (replacing an old one only when asked to)."""
        assert self._tmp is not None
        built = self._tmp / self.path.name
        if self.path.exists():
            check_output(self.path, self.overwrite)
            old = self._tmp / "replaced"
            self.path.rename(old)
        built.rename(self.path)
        self._discard()

    def _discard(self) -> None:
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None
