"""Ground-truth disparity kept beside a bag, keyed by the frames' header stamps.

Disparities are 16-bit PNGs (`value / gt_scale` px, 0 = unknown), a fraction of the size of PFM, and
masks 8-bit PNGs (255 = counted); `index.yaml` maps each stamp to its files and the scene it came from.
Like the bag, the folder appears under its final name only when it is complete.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Literal

import cv2
import numpy as np
import yaml

from stereo_depth.atomic_output import AtomicFolder
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
        self._folder = AtomicFolder(path, overwrite=overwrite)
        self._staging: Path | None = None
        self._frames: list[dict[str, object]] = []

    def __enter__(self) -> GroundTruthWriter:
        self._staging = self._folder.__enter__()
        self._staging.mkdir()
        return self

    def add(self, stamp_ns: int, scene: str, disparity: np.ndarray, mask: np.ndarray | None) -> None:
        assert self._staging is not None, "use GroundTruthWriter as a context manager"
        if np.nanmax(disparity, initial=0.0) * GT_SCALE > 65535:
            msg = f"{scene}: ground-truth disparity above {65535 / GT_SCALE:.0f} px cannot be stored"
            raise BagError(msg)
        stem = f"{len(self._frames):04d}"
        scaled = np.nan_to_num(np.round(disparity * GT_SCALE), nan=0.0).astype(np.uint16)
        cv2.imwrite(str(self._staging / f"{stem}.png"), scaled)
        entry: dict[str, object] = {"stamp_ns": stamp_ns, "scene": scene, "disparity": f"{stem}.png"}
        if mask is not None:
            cv2.imwrite(str(self._staging / f"{stem}_mask.png"), mask.astype(np.uint8) * 255)
            entry["mask"] = f"{stem}_mask.png"
        self._frames.append(entry)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> Literal[False]:
        staging, self._staging = self._staging, None
        if staging is not None and exc_type is None:
            if not self._frames:  # no frame had ground truth: no folder at all
                self._folder.abandon()
                return False
            index = {"gt_scale": GT_SCALE, "frames": self._frames}
            (staging / INDEX).write_text(yaml.safe_dump(index, sort_keys=False))
        return self._folder.__exit__(exc_type, exc, tb)


def read_ground_truth_index(path: Path) -> dict[int, GroundTruthFrame]:
    """{stamp_ns: frame} from a folder written by GroundTruthWriter; a damaged index is one BagError."""
    index_path = path / INDEX
    if not index_path.exists():
        msg = f"{path}: no {INDEX}; expected a ground-truth folder written by stereo-depth make-bag"
        raise BagError(msg)
    try:
        index = yaml.safe_load(index_path.read_text())
        calib = {"gt_scale": str(float(index["gt_scale"]))}
        entries = [(int(e["stamp_ns"]), str(e["scene"]), str(e["disparity"]), e.get("mask")) for e in index["frames"]]
    except (yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
        msg = (
            f"{index_path}: not a ground-truth index ({type(exc).__name__}: {exc}); expected gt_scale and "
            "frames: [{stamp_ns, scene, disparity, mask}], as stereo-depth make-bag --gt writes it"
        )
        raise BagError(msg) from exc
    frames = {}
    for stamp_ns, scene, disparity_file, mask_file in entries:
        disparity = read_ground_truth(path, {**calib, "gt_file": disparity_file})
        if disparity is None:
            msg = f"{path}: {disparity_file} is listed in {INDEX} but missing"
            raise BagError(msg)
        mask: np.ndarray | None = None
        if mask_file is not None:
            pixels = cv2.imread(str(path / str(mask_file)), cv2.IMREAD_GRAYSCALE)
            if pixels is None:
                msg = f"{path}: {mask_file} is listed in {INDEX} but missing or unreadable"
                raise BagError(msg)
            mask = np.asarray(pixels == 255)
        frames[stamp_ns] = GroundTruthFrame(stamp_ns, scene, disparity, mask)
    return frames
