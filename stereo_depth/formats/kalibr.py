"""Kalibr `camchain.yaml` (cam0 = left, cam1 = right, cam2 = a colour camera) -> CameraInfos.

Kalibr writes raw pinhole intrinsics `[fu, fv, cu, cv]`, `distortion_model` radtan or equidistant,
`distortion_coeffs`, `resolution` and, for cam1, `T_cn_cnm1`: the 4x4 transform of points from cam0's
frame into cam1's. That is exactly what cv2.stereoRectify takes, so the rectification is computed once,
as for EuRoC's sensor.yaml files. A third camera (cam2, registered depth) has its `T_cn_cnm1` relative
to cam1, again mapping points the other way from a pose: `read_camchain_colour` chains it onto cam1's and
inverts the product into the colour camera's pose in cam0 (`rgb_in_left`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from stereo_depth.core.camera import CameraInfo
from stereo_depth.core.pose import Pose
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


def _document(path: Path) -> dict[str, Any]:
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        msg = f"{path}: cannot read it as YAML ({exc})"
        raise CalibrationError(msg) from exc
    if not isinstance(document, dict):
        msg = f"{path}: expected a Kalibr camchain.yaml (a mapping with cam0 and cam1)"
        raise CalibrationError(msg)
    return document


def _to_previous(camera: dict[str, Any], name: str, path: Path) -> np.ndarray:
    """`T_cn_cnm1`: the 4x4 transform of points from the camera before `name` into `name`'s frame."""
    if "T_cn_cnm1" not in camera:
        msg = f"{path}: {name} has no T_cn_cnm1 (the transform from the camera before it); run Kalibr's calibration"
        raise CalibrationError(msg)
    transform = np.asarray(camera["T_cn_cnm1"], dtype=np.float64)
    if transform.shape != (4, 4):
        msg = f"{path}: {name} T_cn_cnm1 is {transform.shape}, expected a 4x4 matrix"
        raise CalibrationError(msg)
    return transform


def read_camchain_colour(path: Path, frame_id: str = "cam2") -> tuple[CameraInfo, Pose] | None:
    """cam2 of a Kalibr camchain.yaml, the colour camera: its CameraInfo (raw intrinsics, R = I, P = [K | 0])
    and its pose in cam0's frame; None when the camchain has no cam2."""
    document = _document(path)
    if "cam2" not in document:
        return None
    colour = _camera(document, "cam2", path)
    with calibration_values(path):
        t_10 = _to_previous(_camera(document, "cam1", path), "cam1", path)
        t_21 = _to_previous(colour, "cam2", path)
        k, d, model = _intrinsics(colour, "cam2", path)
        width, height = (int(v) for v in colour["resolution"])
        t_02 = np.linalg.inv(t_21 @ t_10)  # cam0 -> cam2 chained, then inverted: cam2's pose in cam0
        info = CameraInfo.from_values(width, height, k, d, np.eye(3), np.hstack([k, np.zeros((3, 1))]), model, frame_id)
        return info, pose_of(t_02)


def pose_of(transform: np.ndarray) -> Pose:
    """The Pose of a 4x4 rigid transform (its rotation as a unit quaternion)."""
    rotation = transform[:3, :3]
    angle_axis = cv2.Rodrigues(rotation)[0].ravel()
    angle = float(np.linalg.norm(angle_axis))
    axis = angle_axis / angle if angle > 0 else np.zeros(3)
    half = angle / 2.0
    qx, qy, qz = (float(v) for v in axis * np.sin(half))
    x, y, z = (float(v) for v in transform[:3, 3])
    return Pose.from_list([x, y, z, qx, qy, qz, float(np.cos(half))])


def read_camchain(path: Path, frame_id: str = "cam0") -> tuple[CameraInfo, CameraInfo]:
    """Rectifying (left, right) CameraInfos from a Kalibr camchain.yaml."""
    document = _document(path)
    left, right = _camera(document, "cam0", path), _camera(document, "cam1", path)
    with calibration_values(path):
        t_01 = _to_previous(right, "cam1", path)
        if list(left["resolution"]) != list(right["resolution"]):
            msg = f"{path}: cam0 is {left['resolution']} but cam1 is {right['resolution']}; both need one resolution"
            raise CalibrationError(msg)
        width, height = (int(v) for v in left["resolution"])
        intrinsics = _intrinsics(left, "cam0", path), _intrinsics(right, "cam1", path)
        return rectifying_camera_infos((width, height), *intrinsics, t_01, frame_id)
