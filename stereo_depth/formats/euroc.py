"""EuRoC-style stereo folders: two sensor.yaml files (intrinsics, radtan distortion, T_BS) -> CameraInfos.

EuRoC gives each camera's pose in the body frame; the stereo extrinsics are cam0 -> cam1 =
inv(T_BS1) * T_BS0. cv2.stereoRectify turns that into the R and P that ROS CameraInfo carries.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from stereo_depth.core.camera import CameraInfo
from stereo_depth.errors import CalibrationError

DISTORTION_MODELS = {"radial-tangential": "plumb_bob", "radtan": "plumb_bob", "equidistant": "equidistant"}


@contextmanager
def calibration_values(source: Path | str) -> Iterator[None]:
    """Numbers of the wrong count, type or shape in a calibration file become one CalibrationError that
    names the file, whichever conversion noticed them (float(), reshape, numpy, OpenCV)."""
    try:
        yield
    except (ValueError, TypeError, KeyError, IndexError, np.linalg.LinAlgError, cv2.error) as exc:
        msg = f"{source}: malformed calibration values ({type(exc).__name__}: {exc}); check its numbers"
        raise CalibrationError(msg) from exc


def read_sensor_yaml(path: Path) -> dict[str, Any]:
    text = path.read_text()
    if text.startswith("%YAML"):
        text = text.split("\n", 1)[1]  # OpenCV-style directive that PyYAML rejects
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        msg = f"{path}: not valid YAML ({exc})"
        raise CalibrationError(msg) from exc
    if not isinstance(data, dict):
        msg = f"{path}: expected a mapping of EuRoC camera keys"
        raise CalibrationError(msg)
    for key in ("T_BS", "resolution", "intrinsics", "distortion_coefficients"):
        if key not in data:
            msg = f"{path}: missing '{key}'; expected an EuRoC camera sensor.yaml"
            raise CalibrationError(msg)
    return data


def _pose(data: dict[str, Any]) -> np.ndarray:
    return np.asarray(data["T_BS"]["data"], dtype=np.float64).reshape(4, 4)


Intrinsics = tuple[np.ndarray, np.ndarray, str]  # K, D, ROS distortion model


def pinhole_intrinsics(values: Any, model_name: str, coefficients: Any, source: str) -> Intrinsics:
    """K, D and the ROS distortion model from [fu, fv, cu, cv] and an EuRoC / Kalibr model name."""
    fu, fv, cu, cv = (float(v) for v in values)
    k = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    model = DISTORTION_MODELS.get(model_name)
    if model is None:
        msg = f"{source}: distortion model '{model_name}' is not supported; use one of {sorted(DISTORTION_MODELS)}"
        raise CalibrationError(msg)
    d = np.asarray(coefficients, dtype=np.float64)
    if model == "plumb_bob":
        d = np.concatenate([d, np.zeros(max(0, 5 - d.size))])[:5]
    return k, d, model


def _intrinsics(data: dict[str, Any], source: Path) -> Intrinsics:
    model = str(data.get("distortion_model", "radial-tangential"))
    return pinhole_intrinsics(data["intrinsics"], model, data["distortion_coefficients"], str(source))


def stereo_camera_infos(left_yaml: Path, right_yaml: Path, frame_id: str = "cam0") -> tuple[CameraInfo, CameraInfo]:
    """Rectifying CameraInfos for the pair (alpha 0: only valid pixels in the rectified images)."""
    left, right = read_sensor_yaml(left_yaml), read_sensor_yaml(right_yaml)
    with calibration_values(f"{left_yaml} / {right_yaml}"):
        width, height = (int(v) for v in left["resolution"])
        t_01 = np.linalg.inv(_pose(right)) @ _pose(left)  # points in cam0 -> cam1
        intrinsics = _intrinsics(left, left_yaml), _intrinsics(right, right_yaml)
        return rectifying_camera_infos((width, height), *intrinsics, t_01, frame_id)


def rectifying_camera_infos(
    size: tuple[int, int], left: Intrinsics, right: Intrinsics, t_01: np.ndarray, frame_id: str
) -> tuple[CameraInfo, CameraInfo]:
    """The R and P that camera_calibration would write, from raw intrinsics and the 4x4 transform of
    points from the left camera into the right one (cv2.stereoRectify, alpha 0, zero disparity at
    infinity); computed once per calibration file, not per frame."""
    (k0, d0, model0), (k1, d1, model1) = left, right
    if model0 != model1:
        msg = f"left uses {model0} distortion but right uses {model1}; both must use one model"
        raise CalibrationError(msg)
    rotation, translation = t_01[:3, :3], t_01[:3, 3].reshape(3, 1)
    width, height = size
    if model0 == "equidistant":
        r0, r1, p0, p1, _ = cv2.fisheye.stereoRectify(
            k0, d0[:4], k1, d1[:4], size, rotation, translation, flags=cv2.CALIB_ZERO_DISPARITY
        )
    else:
        r0, r1, p0, p1, _, _, _ = cv2.stereoRectify(
            k0, d0, k1, d1, size, rotation, translation, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
        )
    return (
        CameraInfo.from_values(width, height, k0, d0, r0, p0, model0, frame_id),
        CameraInfo.from_values(width, height, k1, d1, r1, p1, model1, frame_id),
    )
