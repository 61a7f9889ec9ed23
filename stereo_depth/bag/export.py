"""Files a person opens without ROS: a picture per frame and a PLY point cloud."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.metrics import colorize_disparity

PLY_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def as_bgr(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)


def disparity_picture(left_rect: np.ndarray, disparity: np.ndarray, max_disparity: float) -> np.ndarray:
    """Rectified left | colourised disparity (TURBO: near = red, far = blue, black = no disparity).

    One fixed colour scale per run (the search range), so a colour means the same depth in every frame.
    """
    return np.hstack([as_bgr(left_rect), colorize_disparity(disparity, max_disparity)])


def write_ply(path: Path, points: np.ndarray, color: np.ndarray) -> int:
    """Binary little-endian PLY of the valid points with their colour; returns the number of points.

    MeshLab, CloudCompare and Open3D read it; invalid (NaN) points are left out, as viewers expect.
    """
    valid = np.isfinite(points).all(axis=2)
    bgr = as_bgr(color)
    vertices = np.empty(int(valid.sum()), dtype=PLY_VERTEX)
    xyz = points[valid]
    vertices["x"], vertices["y"], vertices["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rgb = bgr[valid]
    vertices["red"], vertices["green"], vertices["blue"] = rgb[:, 2], rgb[:, 1], rgb[:, 0]
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment stereo_depth: left optical frame, metres\n"
        f"element vertex {vertices.size}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    with path.open("wb") as out:
        out.write(header.encode("ascii"))
        out.write(vertices.tobytes())
    return int(vertices.size)


def read_ply(path: Path) -> np.ndarray:
    """The vertices of a PLY written by `write_ply` (for tests and quick checks)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return np.frombuffer(data[end:], dtype=PLY_VERTEX)
