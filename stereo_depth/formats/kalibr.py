"""Kalibr `camchain.yaml` (cam0 = left, cam1 = right) -> rectifying CameraInfos.

Kalibr writes raw pinhole intrinsics `[fu, fv, cu, cv]`, `distortion_model` radtan or equidistant,
`distortion_coeffs`, `resolution` and, for cam1, `T_cn_cnm1`: the 4x4 transform of points from cam0's
frame into cam1's. That is exactly what cv2.stereoRectify takes, so the rectification is computed once,
as for EuRoC's sensor.yaml files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from stereo_depth.core.camera import CameraInfo
from stereo_depth.errors import CalibrationError
from stereo_depth.formats.euroc import Intrinsics, calibration_values, pinhole_intrinsics, rectifying_camera_infos

CAMERA_KEYS = ("intrinsics", "distortion_model", "distortion_coeffs", "resolution")


def is_camchain(path: Path) -> bool:
    """A YAML file whose top level has cam0 and cam1 (what Kalibr writes, whatever the file is called)."""
    if not path.is_file() or path.suffix not in (".yaml", ".yml"):
        return False
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return False
    return isinstance(document, dict) and "cam0" in document and "cam1" in document


def _camera(document: dict[str, Any], name: str, path: Path) -> dict[str, Any]:
    camera = document.get(name)
    if not isinstance(camera, dict):
        msg = f"{path}: no '{name}' mapping; expected a Kalibr camchain.yaml with cam0 (left) and cam1 (right)"
        raise CalibrationError(msg)
    missing = [key for key in CAMERA_KEYS if key not in camera]
    if missing:
        msg = f"{path}: {name} has no {', '.join(missing)}; expected Kalibr's camchain keys {', '.join(CAMERA_KEYS)}"
        raise CalibrationError(msg)
    model = camera.get("camera_model", "pinhole")
    if model != "pinhole":
        msg = f"{path}: {name} uses camera_model '{model}'; only pinhole cameras (radtan or equidistant) are supported"
        raise CalibrationError(msg)
    return camera


def _intrinsics(camera: dict[str, Any], name: str, path: Path) -> Intrinsics:
    source = f"{path} {name}"
    return pinhole_intrinsics(
        camera["intrinsics"], str(camera["distortion_model"]), camera["distortion_coeffs"], source
    )


def read_camchain(path: Path, frame_id: str = "cam0") -> tuple[CameraInfo, CameraInfo]:
    """Rectifying (left, right) CameraInfos from a Kalibr camchain.yaml."""
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        msg = f"{path}: cannot read it as YAML ({exc})"
        raise CalibrationError(msg) from exc
    if not isinstance(document, dict):
        msg = f"{path}: expected a Kalibr camchain.yaml (a mapping with cam0 and cam1)"
        raise CalibrationError(msg)
    left, right = _camera(document, "cam0", path), _camera(document, "cam1", path)
    with calibration_values(path):
        if "T_cn_cnm1" not in right:
            msg = f"{path}: cam1 has no T_cn_cnm1 (the cam0 -> cam1 transform); run Kalibr's stereo calibration"
            raise CalibrationError(msg)
        t_01 = np.asarray(right["T_cn_cnm1"], dtype=np.float64)
        if t_01.shape != (4, 4):
            msg = f"{path}: cam1 T_cn_cnm1 is {t_01.shape}, expected a 4x4 matrix"
            raise CalibrationError(msg)
        if list(left["resolution"]) != list(right["resolution"]):
            msg = f"{path}: cam0 is {left['resolution']} but cam1 is {right['resolution']}; both need one resolution"
            raise CalibrationError(msg)
        width, height = (int(v) for v in left["resolution"])
        intrinsics = _intrinsics(left, "cam0", path), _intrinsics(right, "cam1", path)
        return rectifying_camera_infos((width, height), *intrinsics, t_01, frame_id)
