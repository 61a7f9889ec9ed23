"""Disparity to depth and organized point clouds.

Z = fx * B / (d - (cx_left - cx_right)); X and Y scale the pixel's ray by Z. The per-pixel rays depend
only on the calibration, so they are computed once per calibration and reused.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereo_depth.core.camera import StereoCamera
from stereo_depth.errors import CalibrationError


@dataclass
class Rays:
    """(u - cx) / fx along a row and (v - cy) / fy down a column, for one calibration and size."""

    x: np.ndarray  # shape (1, W)
    y: np.ndarray  # shape (H, 1)

    @classmethod
    def for_camera(cls, camera: StereoCamera) -> Rays:
        u = np.arange(camera.width, dtype=np.float32)
        v = np.arange(camera.height, dtype=np.float32)
        return cls(
            x=((u - camera.cx_left) / camera.fx).reshape(1, -1).astype(np.float32),
            y=((v - camera.cy) / camera.fy).reshape(-1, 1).astype(np.float32),
        )


def disparity_to_depth(
    disparity: np.ndarray,
    camera: StereoCamera,
    out: np.ndarray | None = None,
    *,
    offset_adjusted: bool = False,
) -> np.ndarray:
    """Depth in metres, NaN where the disparity is invalid or not in front of the camera.

    `offset_adjusted`: the disparity already has cx_left - cx_right subtracted (a DisparityImage's
    contents), so it must not be subtracted again; the arithmetic is otherwise the same, bit for bit.
    """
    if camera.no_depth_reason is not None:
        raise CalibrationError(camera.no_depth_reason)
    offset = 0.0 if offset_adjusted else camera.disparity_offset
    d: np.ndarray = np.subtract(disparity, np.float32(offset), out=out, dtype=np.float32)
    d[~(d > 0)] = np.nan
    np.divide(np.float32(camera.fx * camera.baseline), d, out=d)
    return d


def point_planes(depth: np.ndarray, rays: Rays) -> list[np.ndarray]:
    """X, Y and Z of every pixel as three (H, W) float32 planes, in the left optical frame (x right,
    y down, z forward); NaN invalid."""
    return [
        np.multiply(depth, rays.x, dtype=np.float32),
        np.multiply(depth, rays.y, dtype=np.float32),
        np.ascontiguousarray(depth, np.float32),
    ]


def depth_to_points(depth: np.ndarray, rays: Rays) -> np.ndarray:
    """Organized (H, W, 3) float32 XYZ: `point_planes` interleaved."""
    points: np.ndarray = cv2.merge(point_planes(depth, rays))
    return points


def voxel_thinned(xyz: np.ndarray, rgb: np.ndarray | None, size: float) -> tuple[np.ndarray, np.ndarray | None]:
    """One point per occupied cube of edge `size` (metres): the centroid of its points, and the colour
    of one of them (a mean of packed colours would be no colour at all). Sorting by cube is the cost."""
    if len(xyz) == 0:
        return xyz, rgb
    scale = np.float32(1.0 / size)
    ids = np.zeros(len(xyz), np.int64)
    for axis in range(3):  # column by column: reductions over an (N, 3) array's axis 0 are slow
        cell = np.floor(xyz[:, axis] * scale).astype(np.int64)
        low = cell.min()
        ids *= cell.max() - low + 1
        ids += cell - low
    order = np.argsort(ids)
    ids = ids[order]
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    counts = np.diff(np.r_[starts, len(ids)])
    centroids = np.empty((len(starts), 3), np.float32)
    for axis in range(3):
        centroids[:, axis] = np.add.reduceat(xyz[order, axis], starts, dtype=np.float64) / counts
    return centroids, rgb[order[starts]] if rgb is not None else None
