"""Ground-truth disparity kept beside a bag, keyed by the frames' header stamps.

Disparities are 16-bit PNGs (`value / gt_scale` px, 0 = unknown), a fraction of the size of PFM, and
masks 8-bit PNGs (255 = counted); `index.yaml` maps each stamp to its files and the scene it came from.
Like the bag, the folder appears under its final name only when it is complete.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Literal

import cv2
import numpy as np
import yaml

from stereo_depth.bag.writer import check_output
from stereo_depth.errors import BagError
from stereo_depth.formats.scenes import read_ground_truth

GT_SCALE = 64  # 1/64 px steps, disparities up to 1023 px
INDEX = "index.yaml"


@dataclass
class GroundTruthFrame:
    stamp_ns: int
    scene: str
    disparity: np.ndarray  # float32 px, NaN unknown
    mask: np.ndarray | None  # bool, True = counted


class GroundTruthWriter:
    def __init__(self, path: Path, *, overwrite: bool = False) -> None:
        self.path = path
        self.overwrite = overwrite
        self._tmp: Path | None = None
        self._frames: list[dict[str, object]] = []

    def __enter__(self) -> GroundTruthWriter:
        check_output(self.path, self.overwrite)
        self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
        return self

    def add(self, stamp_ns: int, scene: str, disparity: np.ndarray, mask: np.ndarray | None) -> None:
        assert self._tmp is not None, "use GroundTruthWriter as a context manager"
        if np.nanmax(disparity, initial=0.0) * GT_SCALE > 65535:
            msg = f"{scene}: ground-truth disparity above {65535 / GT_SCALE:.0f} px cannot be stored"
            raise BagError(msg)
        stem = f"{len(self._frames):04d}"
        scaled = np.nan_to_num(np.round(disparity * GT_SCALE), nan=0.0).astype(np.uint16)
        cv2.imwrite(str(self._tmp / f"{stem}.png"), scaled)
        entry: dict[str, object] = {"stamp_ns": stamp_ns, "scene": scene, "disparity": f"{stem}.png"}
        if mask is not None:
            cv2.imwrite(str(self._tmp / f"{stem}_mask.png"), mask.astype(np.uint8) * 255)
            entry["mask"] = f"{stem}_mask.png"
        self._frames.append(entry)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        tmp, self._tmp = self._tmp, None
        if tmp is None:
            return False
        try:
            if exc_type is None and self._frames:
                index = {"gt_scale": GT_SCALE, "frames": self._frames}
                (tmp / INDEX).write_text(yaml.safe_dump(index, sort_keys=False))
                tmp.chmod(0o755)  # mkdtemp makes it private
                if self.path.exists():
                    shutil.rmtree(self.path)
                tmp.rename(self.path)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return False


def read_ground_truth_index(path: Path) -> dict[int, GroundTruthFrame]:
    """{stamp_ns: frame} from a folder written by GroundTruthWriter."""
    index_path = path / INDEX
    if not index_path.exists():
        msg = f"{path}: no {INDEX}; expected a ground-truth folder written by stereo-depth make-bag"
        raise BagError(msg)
    index = yaml.safe_load(index_path.read_text())
    calib = {"gt_scale": str(index["gt_scale"])}
    frames = {}
    for entry in index["frames"]:
        disparity = read_ground_truth(path, {**calib, "gt_file": entry["disparity"]})
        if disparity is None:
            msg = f"{path}: {entry['disparity']} is listed in {INDEX} but missing"
            raise BagError(msg)
        mask: np.ndarray | None = None
        if "mask" in entry:
            mask = np.asarray(cv2.imread(str(path / entry["mask"]), cv2.IMREAD_GRAYSCALE) == 255)
        frames[int(entry["stamp_ns"])] = GroundTruthFrame(int(entry["stamp_ns"]), entry["scene"], disparity, mask)
    return frames
