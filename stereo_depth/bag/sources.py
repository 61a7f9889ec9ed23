"""Stereo image sources on disk, read as a stream of calibrated pairs for `make-bag`.

Three layouts, so that KITTI, Middlebury and one's own captures can be brought into ROS:

- scene folders (shared/data layout): `left.png`, `right.png`, `calib.txt`, optional ground truth;
  several folders become consecutive frames of one rectified stream;
- a sequence folder: `left/` and `right/` images paired by file name, calibrated by `calib.txt`
  (rectified), or any layout `formats.calibration_files` knows (camera_info YAML, EuRoC, Kalibr);
- a EuRoC folder: `mav0/cam0/data/*.png` with `mav0/cam0/sensor.yaml` (and cam1).

Sequence images are read one pair at a time, so long captures do not have to fit in memory.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.camera import CameraInfo
from stereo_depth.errors import BagError
from stereo_depth.formats.calibration_files import find_stereo_calibration
from stereo_depth.formats.scenes import Scene, load_scene, read_calib

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".tif", ".tiff", ".bmp")


@dataclass
class SourceFrame:
    name: str
    left: np.ndarray
    right: np.ndarray
    left_info: CameraInfo
    right_info: CameraInfo
    stamp_ns: int | None  # from the file name when it is a nanosecond timestamp
    gt: np.ndarray | None = None  # float32 px, NaN unknown
    mask: np.ndarray | None = None  # bool, True = counted (non-occluded)


@dataclass(frozen=True)
class Sequence:
    """A folder of paired images and the calibration that belongs to them."""

    pairs: list[tuple[Path, Path]]
    left_info: CameraInfo | None  # None: from calib.txt, which needs the image size first
    right_info: CameraInfo | None
    calib: dict[str, str]


def is_scene(folder: Path) -> bool:
    return any((folder / f"left{s}").exists() for s in IMAGE_SUFFIXES)


def read_frames(paths: list[Path]) -> Iterator[SourceFrame]:
    """Frames from scene folders (any number) or from one sequence / EuRoC folder."""
    for path in paths:
        if not path.is_dir():
            msg = f"{path} is not a folder; pass scene folders or one folder with left/ and right/ images"
            raise BagError(msg)
    if all(is_scene(p) for p in paths):
        yield from (_scene_frame(load_scene(p)) for p in paths)
        return
    if len(paths) != 1:
        msg = "pass either scene folders (left.png, right.png, calib.txt) or exactly one sequence folder"
        raise BagError(msg)
    yield from _sequence_frames(find_sequence(paths[0]))


def _scene_frame(scene: Scene) -> SourceFrame:
    left_info, right_info = scene.camera_infos()
    return SourceFrame(scene.name, scene.left, scene.right, left_info, right_info, None, scene.gt, scene.mask)


def _stamp(path: Path) -> int | None:
    return int(path.stem) if path.stem.isdigit() and len(path.stem) >= 10 else None


def _images(folder: Path) -> dict[str, Path]:
    return {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES}


def _image_folders(root: Path) -> tuple[Path, Path] | None:
    for left, right in (("left", "right"), ("cam0/data", "cam1/data"), ("image_0", "image_1"), ("image_2", "image_3")):
        if (root / left).is_dir() and (root / right).is_dir():
            return root / left, root / right
    return None


def find_sequence(root: Path) -> Sequence:
    if (root / "mav0").is_dir():
        root = root / "mav0"
    folders = _image_folders(root)
    if folders is None:
        msg = f"{root}: no left/ and right/ (or cam0/data and cam1/data) image folders and no left.png"
        raise BagError(msg)
    left, right = _images(folders[0]), _images(folders[1])
    common = sorted(set(left) & set(right))
    if not common:
        msg = f"{root}: no image appears in both {folders[0].name}/ and {folders[1].name}/ under one file name"
        raise BagError(msg)
    pairs = [(left[k], right[k]) for k in common]
    infos = find_stereo_calibration(root)
    calib = read_calib(root / "calib.txt") if infos is None else {}
    if infos is None and not calib:
        msg = (
            f"{root}: no calibration; add cam0_sensor.yaml + cam1_sensor.yaml (EuRoC), "
            "left.yaml + right.yaml (ROS camera_info), camchain.yaml (Kalibr) or calib.txt (Middlebury, rectified)"
        )
        raise BagError(msg)
    left_info, right_info = infos if infos is not None else (None, None)
    return Sequence(pairs, left_info, right_info, calib)


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        msg = f"cannot read image {path}"
        raise BagError(msg)
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


def _sequence_frames(sequence: Sequence) -> Iterator[SourceFrame]:
    for left_path, right_path in sequence.pairs:
        left, right = _read_image(left_path), _read_image(right_path)
        if sequence.left_info is not None and sequence.right_info is not None:
            infos = (sequence.left_info, sequence.right_info)
        else:
            infos = Scene(left_path.stem, left, right, sequence.calib, None, None).camera_infos()
        yield SourceFrame(left_path.stem, left, right, *infos, _stamp(left_path))


# ---------------------------------------------------------------- changing frames


def _shift_principal_point(info: CameraInfo, x0: int, y0: int, width: int, height: int) -> CameraInfo:
    k, p = info.k.copy(), info.p.copy()
    k[0, 2] -= x0
    k[1, 2] -= y0
    p[0, 2] -= x0
    p[1, 2] -= y0
    return dataclasses.replace(info, width=width, height=height, k=k, p=p)


def crop(frame: SourceFrame, width: int, height: int) -> SourceFrame:
    """The centre width x height of both images and the GT; K and P move with the crop, disparities stay."""
    h, w = frame.left.shape[:2]
    if width > w or height > h:
        msg = f"{frame.name} is {w}x{h}, smaller than the crop {width}x{height}"
        raise BagError(msg)
    x0, y0 = (w - width) // 2, (h - height) // 2
    window = (slice(y0, y0 + height), slice(x0, x0 + width))
    return SourceFrame(
        frame.name,
        np.ascontiguousarray(frame.left[window]),
        np.ascontiguousarray(frame.right[window]),
        _shift_principal_point(frame.left_info, x0, y0, width, height),
        _shift_principal_point(frame.right_info, x0, y0, width, height),
        frame.stamp_ns,
        None if frame.gt is None else np.ascontiguousarray(frame.gt[window]),
        None if frame.mask is None else np.ascontiguousarray(frame.mask[window]),
    )
