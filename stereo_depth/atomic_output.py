"""Output folders that appear under their final name complete, or not at all.

Every command that writes a folder (a bag, a ground-truth folder, a calibration) stages it in a hidden
folder beside the target, on the same filesystem, and publishes it only when the work succeeded: the
old folder is moved aside in one rename, the new one moved in with another, and only then is the old
one deleted. An error or Ctrl-C at any point leaves the old folder (or nothing) in place, never a half
one; no step deletes before the new folder is in place.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Literal

from stereo_depth.errors import StereoDepthError


class OutputError(StereoDepthError):
    """An output folder cannot be written where asked."""


def check_output(path: Path, overwrite: bool, *, is_file: bool = False) -> None:
    """Refuse before any work is done, so a long run does not fail at its end. `is_file`: the output is
    one file (a ROS 1 bag), not a folder."""
    if path.exists() and not overwrite:
        msg = f"{path} exists already; choose another output name or pass --overwrite"
        raise OutputError(msg)
    if path.exists() and not path.is_dir() and not is_file:
        msg = f"{path} is a file; pass a folder name"
        raise OutputError(msg)
    if path.is_dir() and is_file:
        msg = f"{path} is a folder; pass a file name"
        raise OutputError(msg)
    if not path.parent.is_dir():
        msg = f"{path.parent} is not a folder; create it first"
        raise OutputError(msg)
    if not os.access(path.parent, os.W_OK | os.X_OK):
        msg = f"cannot write in {path.parent} (permission denied); choose an output folder you can write to"
        raise OutputError(msg)


class AtomicFolder:
    """`with AtomicFolder(path, overwrite=...) as staging:` fill `staging` (it does not exist yet:
    create it, or let a writer create it); it becomes `path` when the block ends without an error.
    With `is_file` the output is one file written at `staging` (a ROS 1 bag), published the same way."""

    def __init__(self, path: Path, *, overwrite: bool = False, is_file: bool = False) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        self.is_file = is_file
        self._tmp: Path | None = None

    def __enter__(self) -> Path:
        check_output(self.path, self.overwrite, is_file=self.is_file)
        try:
            self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
        except OSError as exc:  # read-only file system, or a permission os.access did not foresee
            msg = f"cannot write in {self.path.parent} ({exc.strerror}); choose an output folder you can write to"
            raise OutputError(msg) from exc
        return self._tmp / self.path.name

    def abandon(self) -> None:
        """Publish nothing: the staging folder goes, an existing output stays as it was."""
        self.__exit__(OutputError, None, None)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        tmp, self._tmp = self._tmp, None
        if tmp is None:
            return False
        try:
            if exc_type is None:
                self._publish(tmp / self.path.name, tmp / "replaced")
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return False

    def _publish(self, built: Path, aside: Path) -> None:
        if not (built.is_file() if self.is_file else built.is_dir()):
            msg = f"nothing was written for {self.path}"
            raise OutputError(msg)
        if self.path.exists():
            check_output(self.path, self.overwrite, is_file=self.is_file)  # it may have appeared while we worked
            self.path.rename(aside)
        try:
            built.rename(self.path)
        except OSError:
            if aside.exists():
                aside.rename(self.path)  # put the old one back
            raise
