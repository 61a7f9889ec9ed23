"""Depth registered to another camera (a colour camera beside the stereo pair): each valid depth pixel
moved into that camera and projected into its undistorted image.

Forward projection with a z-buffer: where several depth pixels land on one colour pixel, the nearest
wins, so a surface hidden behind another from the colour camera's view never shows through it. A
colour camera of finer resolution (or nearer the scene) than the depth leaves one-pixel cracks between
the projected pixels of one surface; those are closed, and only those: an empty pixel whose two
opposite neighbours (left and right, above and below, or diagonal, where a row crack crosses a column
crack) agree in depth takes their mean, as does a pixel seen through such a crack (farther than both).
A pixel the depth camera could not see stays invalid (NaN); nothing is interpolated across depth edges.

The transform is composed here once per calibration: the depth is in the left camera's rectified
frame, the pose given (`rgb_in_left`) is the colour camera's optical frame in the left camera's frame
as calibrated (raw), and the colour camera's own camera_info R (identity for a single camera) turns
its frame into its rectified one.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from stereo_depth.core.geometry import Rays
from stereo_depth.core.pose import Pose

# Two neighbours whose depths differ by at most this fraction of the nearer are one surface (a crack
# between them is closed); farther apart they are an edge, and the pixel between them is left as it is.
CRACK_DEPTH_STEP = 0.05


@dataclass(frozen=True)
class PinholeModel:
    """An undistorted camera: its image size and the projection of its (rectified) frame."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def rays(self) -> Rays:
        """Each pixel's ray, as the depth's (a cloud of the registered depth)."""
        u = np.arange(self.width, dtype=np.float64)
        v = np.arange(self.height, dtype=np.float64)
        return Rays(
            x=((u - self.cx) / self.fx).astype(np.float32).reshape(1, -1),
            y=((v - self.cy) / self.fy).astype(np.float32).reshape(-1, 1),
        )


@dataclass(frozen=True)
class RigidMotion:
    """X_target = rotation @ X_source + translation (metres)."""

    rotation: np.ndarray  # (3, 3) float64
    translation: np.ndarray  # (3,) float64


def left_rectified_to_colour(pose: Pose, left_r: np.ndarray, colour_r: np.ndarray) -> RigidMotion:
    """The motion from the left camera's rectified frame (where the depth is) to the colour camera's
    rectified frame (where it is projected), given `pose`: the colour camera in the left camera's raw
    frame (p_left = R p_colour + t), and each camera_info's R (raw -> rectified)."""
    rotation = pose.rotation_matrix()
    to_colour = colour_r @ rotation.T
    return RigidMotion(to_colour @ left_r.T, -(to_colour @ np.asarray(pose.translation, dtype=np.float64)))


def register_depth(depth: np.ndarray, rays: Rays, motion: RigidMotion, target: PinholeModel) -> np.ndarray:
    """Depth (float32 metres, NaN invalid) with its pixels' rays, as seen by `target`: (H', W') float32
    metres along the target's optical axis, NaN where it sees nothing the depth saw."""
    projected = np.full((target.height, target.width), np.inf, np.float32)
    out = np.empty_like(projected)
    kernels = _kernels()
    kernels[0](
        np.ascontiguousarray(depth, np.float32),
        np.ascontiguousarray(rays.x, np.float32).ravel(),
        np.ascontiguousarray(rays.y, np.float32).ravel(),
        np.ascontiguousarray(motion.rotation, np.float64).ravel(),
        np.ascontiguousarray(motion.translation, np.float64),
        np.array([target.fx, target.fy, target.cx, target.cy], np.float64),
        projected,
    )
    kernels[1](projected, np.float32(CRACK_DEPTH_STEP), out)
    return out


def compile_registration_kernels() -> None:
    """Compile (or load from numba's cache) the two kernels now, not on a first frame."""
    register_depth(
        np.ones((2, 2), np.float32),
        Rays(x=np.zeros((1, 2), np.float32), y=np.zeros((2, 1), np.float32)),
        RigidMotion(np.eye(3), np.zeros(3)),
        PinholeModel(3, 3, 1.0, 1.0, 1.0, 1.0),
    )


@functools.cache
def _kernels() -> tuple[Any, Any]:
    import numba  # only the streams that register depth load numba for it

    jit = numba.njit(cache=True, nogil=True)
    return jit(_project), jit(_close_cracks)


def _project(
    depth: np.ndarray,
    rays_x: np.ndarray,
    rays_y: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    intrinsics: np.ndarray,
    out: np.ndarray,
) -> None:
    """Each valid depth pixel into `out` (inf: empty) at its nearest pixel, the nearest depth kept."""
    height, width = depth.shape
    out_height, out_width = out.shape
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation
    tx, ty, tz = translation
    fx, fy, cx, cy = intrinsics
    for v in range(height):
        ray_y = rays_y[v]
        for u in range(width):
            z = depth[v, u]
            if not z > 0:  # NaN too
                continue
            x = rays_x[u] * z
            y = ray_y * z
            xt = r00 * x + r01 * y + r02 * z + tx
            yt = r10 * x + r11 * y + r12 * z + ty
            zt = r20 * x + r21 * y + r22 * z + tz
            if not zt > 0:
                continue
            column = np.floor(fx * xt / zt + cx + 0.5)
            row = np.floor(fy * yt / zt + cy + 0.5)
            if 0 <= column < out_width and 0 <= row < out_height:
                target = np.float32(zt)
                if target < out[int(row), int(column)]:
                    out[int(row), int(column)] = target


def _close_cracks(projected: np.ndarray, step: np.float32, out: np.ndarray) -> None:
    """`projected` with its one-pixel cracks closed into `out`, empty (inf) pixels NaN. Read from
    `projected` only, so a closed crack never closes the next one: one pixel, nothing more."""
    height, width = projected.shape
    for v in range(height):
        for u in range(width):
            z = projected[v, u]
            filled = z
            for dv, du in ((0, 1), (1, 0), (1, 1), (1, -1)):  # across, down, and both diagonals
                if not (dv <= v < height - dv and abs(du) <= u < width - abs(du)):
                    continue
                a = projected[v - dv, u - du]
                b = projected[v + dv, u + du]
                if not (a < z and b < z) or a == np.inf or b == np.inf:
                    continue  # only a pixel farther than both (or empty) is a crack
                near = min(a, b)
                if abs(a - b) > step * near:
                    continue  # an edge: the pixel between may be occluded
                mean = np.float32(0.5) * (a + b)
                if z > mean + step * near:  # empty (inf), or seen through the crack
                    filled = mean
                    break
            out[v, u] = filled if filled != np.inf else np.nan
