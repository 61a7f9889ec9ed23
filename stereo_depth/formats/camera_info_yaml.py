"""camera_info YAML files, in the layout ROS camera drivers load through `camera_info_url`.

The layout is camera_calibration_parsers' (`parse_yml.cpp`): image size, `camera_name`, K, the
distortion model and coefficients, R and P, each matrix as `{rows, cols, data}` with a flow-style
`data` list. Reading follows the same rules as that parser, so a file it accepts we accept: a missing
`distortion_model` is plumb_bob, and `camera_name` is not needed (it is not part of the message, so the
CameraInfo read back does not carry it; the frame_id comes from the driver, not from this file).
Numbers are written with Python's shortest round-trip repr, so a file read back gives bit-identical
matrices and therefore the same rectification maps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np
import yaml

from stereo_depth.core.camera import CameraInfo
from stereo_depth.errors import CalibrationError

_MATRICES = (
    ("camera_matrix", "k", 3, 3),
    ("distortion_coefficients", "d", 1, None),
    ("rectification_matrix", "r", 3, 3),
    ("projection_matrix", "p", 3, 4),
)


def camera_info_to_yaml(info: CameraInfo, camera_name: str) -> str:
    """The text of one camera_info file for `info`."""
    lines = [
        f"image_width: {info.width}",
        f"image_height: {info.height}",
        f"camera_name: {camera_name}",
    ]
    for key, attr, rows, cols in _MATRICES:
        values = np.asarray(getattr(info, attr), dtype=np.float64).ravel()
        if key == "distortion_coefficients":
            lines.append(f"distortion_model: {info.distortion_model}")
        data = ", ".join(repr(float(v)) for v in values)
        lines += [
            f"{key}:",
            f"  rows: {rows}",
            f"  cols: {cols if cols is not None else values.size}",
            f"  data: [{data}]",
        ]
    return "\n".join(lines) + "\n"


def _matrix_values(doc: dict[str, Any], key: str, rows: int, cols: int | None, source: str) -> list[float]:
    node = doc.get(key)
    if not isinstance(node, dict) or "data" not in node:
        msg = f"{source}: '{key}' is missing or has no data; expected {{rows, cols, data}}"
        raise CalibrationError(msg)
    declared = (node.get("rows"), node.get("cols"))
    expected_cols = cols if cols is not None else len(node["data"])
    if declared != (rows, expected_cols) or len(node["data"]) != rows * expected_cols:
        msg = (
            f"{source}: '{key}' is {declared[0]}x{declared[1]} with {len(node['data'])} values; "
            f"expected {rows}x{expected_cols}"
        )
        raise CalibrationError(msg)
    try:
        return [float(v) for v in node["data"]]
    except (TypeError, ValueError) as exc:
        msg = f"{source}: '{key}' has a non-numeric value ({exc})"
        raise CalibrationError(msg) from exc


def parse_camera_info_yaml(text: str, source: str = "camera_info") -> CameraInfo:
    """A CameraInfo from the text of a camera_info file; `source` names it in error messages."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        msg = f"{source}: not valid YAML ({exc})"
        raise CalibrationError(msg) from exc
    if not isinstance(doc, dict) or "image_width" not in doc or "image_height" not in doc:
        msg = f"{source}: no image_width/image_height; expected a ROS camera_info YAML file"
        raise CalibrationError(msg)
    k, d, r, p = (_matrix_values(doc, key, rows, cols, source) for key, _, rows, cols in _MATRICES)
    return CameraInfo.from_values(
        doc["image_width"],
        doc["image_height"],
        k,
        d,
        r,
        p,
        distortion_model=str(doc.get("distortion_model", "plumb_bob")),
    )


def read_camera_info_yaml(path: Path) -> CameraInfo:
    """Load a camera_info file (what a driver's camera_info_url points at)."""
    try:
        text = path.read_text()
    except OSError as exc:
        msg = f"{path}: cannot read camera_info file ({exc.strerror})"
        raise CalibrationError(msg) from exc
    return parse_camera_info_yaml(text, str(path))


def read_camera_info_url(url: str) -> CameraInfo:
    """A driver's `camera_info_url` as camera_info_manager takes it: `file:///abs/path.yaml` (or a plain
    path). package:// needs an ament index we may not have: the error says to use file://."""
    if url.startswith("file://"):
        path = Path(unquote(url.removeprefix("file://")))
    elif "://" in url:
        msg = f"camera_info_url '{url}': only file:// URLs (or plain paths) are supported; e.g. file:///path/left.yaml"
        raise CalibrationError(msg)
    else:
        path = Path(url)
    return read_camera_info_yaml(path)
