"""`--camera-info FILE_OR_DIR`: a stereo calibration from whichever file layout the user has.

- a Kalibr camchain.yaml (any file name; cam0 = left, cam1 = right);
- a folder with left.yaml + right.yaml (camera_info YAML: camera_calibration, `stereo-depth calibrate`);
- a EuRoC folder with cam0/sensor.yaml + cam1/sensor.yaml (also mav0/ above them, or cam0_sensor.yaml).

Raw intrinsics and extrinsics (Kalibr, EuRoC) are rectified once here; camera_info files already carry
R and P and are used as they are.
"""

from __future__ import annotations

from pathlib import Path

from stereo_depth.core.camera import CameraInfo
from stereo_depth.errors import CalibrationError
from stereo_depth.formats.camera_info_yaml import read_camera_info_yaml
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.kalibr import is_camchain, read_camchain

StereoInfos = tuple[CameraInfo, CameraInfo]
EUROC_LAYOUTS = (("cam0/sensor.yaml", "cam1/sensor.yaml"), ("cam0_sensor.yaml", "cam1_sensor.yaml"))
KALIBR_NAMES = ("camchain.yaml", "camchain-imucam.yaml")


def find_stereo_calibration(folder: Path) -> StereoInfos | None:
    """The calibration in a folder, or None when it has none of the known layouts."""
    roots = [folder / "mav0", folder] if (folder / "mav0").is_dir() else [folder]
    for root in roots:
        for left, right in EUROC_LAYOUTS:
            if (root / left).is_file() and (root / right).is_file():
                return stereo_camera_infos(root / left, root / right)
    if (folder / "left.yaml").is_file() and (folder / "right.yaml").is_file():
        return read_camera_info_yaml(folder / "left.yaml"), read_camera_info_yaml(folder / "right.yaml")
    for name in KALIBR_NAMES:
        if is_camchain(folder / name):
            return read_camchain(folder / name)
    return None


def read_stereo_calibration(path: Path) -> StereoInfos:
    """(left, right) CameraInfos from a camchain file or a calibration folder; the error lists the layouts."""
    if path.is_file():
        if is_camchain(path):
            return read_camchain(path)
        msg = (
            f"--camera-info {path}: not a Kalibr camchain (no cam0 and cam1); pass a camchain.yaml or a folder "
            "with left.yaml + right.yaml"
        )
        raise CalibrationError(msg)
    if not path.is_dir():
        msg = f"--camera-info {path} does not exist"
        raise CalibrationError(msg)
    found = find_stereo_calibration(path)
    if found is None:
        msg = (
            f"--camera-info {path}: no calibration found; expected a Kalibr camchain.yaml, left.yaml + right.yaml "
            "(camera_info files) or EuRoC cam0/sensor.yaml + cam1/sensor.yaml"
        )
        raise CalibrationError(msg)
    return found
