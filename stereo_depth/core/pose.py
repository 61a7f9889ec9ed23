"""One rigid transform: a translation in metres and a unit quaternion (x, y, z, w), as ROS and tf2 give them.

A pose option is written `[x, y, z, qx, qy, qz, qw]` (what `ros2 run tf2_ros tf2_echo` prints, in that
order). Seven zeros mean "not given": ROS cannot declare an empty list as a list of doubles, so the
option's default must hold numbers, and no rotation has a zero quaternion.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stereo_depth.errors import ParameterError

POSE_LENGTH = 7
QUATERNION_TOLERANCE = 1e-3  # how far from 1 a given quaternion's norm may be (it is normalised then)


@dataclass(frozen=True)
class Pose:
    """Frame B in frame A: `apply` maps a point's B coordinates to its A coordinates (p_A = R p_B + t)."""

    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]  # unit quaternion x, y, z, w; all zero only when unset

    def __post_init__(self) -> None:
        if any(self.as_list()):  # seven zeros: not given
            norm = math.sqrt(sum(q * q for q in self.rotation))
            if abs(norm - 1.0) > QUATERNION_TOLERANCE:
                shown = ", ".join(f"{q:g}" for q in self.rotation)
                msg = f"quaternion ({shown}) has norm {norm:.4f}; give a unit quaternion (x, y, z, w)"
                raise ParameterError(msg)

    @classmethod
    def from_list(cls, values: Sequence[float]) -> Pose:
        """`[x, y, z, qx, qy, qz, qw]`; a quaternion within QUATERNION_TOLERANCE of unit norm is normalised."""
        if len(values) != POSE_LENGTH:
            msg = f"a pose has {POSE_LENGTH} values (x, y, z, qx, qy, qz, qw), got {len(values)}"
            raise ParameterError(msg)
        x, y, z, *quaternion = (float(v) for v in values)
        pose = cls((x, y, z), (quaternion[0], quaternion[1], quaternion[2], quaternion[3]))
        if not pose.is_set:
            return pose
        norm = math.sqrt(sum(q * q for q in quaternion))
        qx, qy, qz, qw = (q / norm for q in quaternion)
        return cls((x, y, z), (qx, qy, qz, qw))

    def as_list(self) -> list[float]:
        return [*self.translation, *self.rotation]

    @property
    def is_set(self) -> bool:
        """False for the seven-zero "not given" value."""
        return any(self.rotation)

    def rotation_matrix(self) -> np.ndarray:
        """The 3x3 rotation (float64) that turns B's axes into A's."""
        if not self.is_set:
            msg = "an unset pose has no rotation; check is_set first"
            raise ValueError(msg)
        return quaternion_matrix(self.rotation)

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous transform (float64): B's points to A's."""
        return pose_matrix(self.translation, self.rotation)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) given in B, in A."""
        moved: np.ndarray = np.asarray(points, dtype=np.float64) @ self.rotation_matrix().T + self.translation
        return moved

    def compose(self, other: Pose) -> Pose:
        """C in A, where self is B in A and `other` is C in B."""
        ax, ay, az, aw = self.rotation
        bx, by, bz, bw = other.rotation
        rotation = (
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        )
        tx, ty, tz = self.apply(np.array(other.translation))
        return Pose((float(tx), float(ty), float(tz)), rotation)

    def inverse(self) -> Pose:
        """A in B."""
        x, y, z, w = self.rotation
        tx, ty, tz = -(self.rotation_matrix().T @ np.array(self.translation))
        return Pose((float(tx), float(ty), float(tz)), (-x, -y, -z, w))


def quaternion_matrix(rotation: Sequence[float]) -> np.ndarray:
    """The 3x3 rotation (float64) of a unit quaternion (x, y, z, w)."""
    x, y, z, w = rotation
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose_matrix(translation: Sequence[float] | np.ndarray, rotation: Sequence[float]) -> np.ndarray:
    """4x4 float64 of a translation and a unit quaternion (x, y, z, w)."""
    out = np.eye(4)
    out[:3, :3] = quaternion_matrix(rotation)
    out[:3, 3] = translation
    return out


UNSET_POSE = Pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))
